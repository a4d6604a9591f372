"""
The ROS 2 node ``rigid_body_sim``: a thin adapter over :class:`~rigid_body_sim.core.Simulation`.

One thread runs both the physics loop and the ROS callbacks: the loop takes a
step when the wall clock says one is due (see :mod:`.pacing`) and, between
steps, lets the executor run callbacks. So a callback never runs during a
step. Wrench messages are queued (the latest per topic) and applied just
before the next step; services (reset, add/remove constraint, step) act
between steps and reply when done. What a step, an input or a reset does is
:class:`.session.Session`'s, shared with the lockstep experiment runner; this
module is the transport, the pacing and the diagnostics.

Topics (private, ``~`` = ``/<namespace>/rigid_body_sim``):

- in: ``~/bodies/<B>/wrench`` (geometry_msgs/WrenchStamped)
- out: ``~/bodies/<B>/pose`` (PoseStamped), ``~/bodies/<B>/twist`` (TwistStamped),
  ``~/body_states`` (rigid_body_sim_interfaces/BodyStates), ``~/metrics``
  (rigid_body_sim_interfaces/Metrics), ``~/markers`` (visualization_msgs/MarkerArray),
  ``~/constraints/<C>/wrench`` (WrenchStamped), ``/clock``, ``/diagnostics``.
- robots (scenes with URDF robots), namespace-relative as ros2_control and
  robot_state_publisher name them: in ``~/joint_commands`` (sensor_msgs/JointState,
  each joint through its interface: effort, position or velocity) and, per command
  group of the scene, ``<group>/commands`` (std_msgs/Float64MultiArray, as
  forward_command_controller's); out ``joint_states`` (sensor_msgs/JointState),
  ``robot_description`` (std_msgs/String, transient local), ``/tf`` and ``/tf_static``
  (tf2_msgs/TFMessage).

See the README for the frames, points and conventions of every message.
"""

from __future__ import annotations

import os
import sys
import time
import traceback
from typing import Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, qos_profile_services_default, \
    QoSProfile, ReliabilityPolicy
from rclpy.service_introspection import ServiceIntrospectionState
from rclpy.signals import SignalHandlerOptions
from rigid_body_sim_interfaces.msg import BodyStates, Contacts, Metrics
from rigid_body_sim_interfaces.srv import AddConstraint, RemoveConstraint, Step
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header, String
from std_srvs.srv import SetBool, Trigger
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from . import conversions as conv
from .inputs import Rejected, Rejection, shown
from .outputs import body_topic, constraint_topic, CONTACTS_TOPIC, group_topic, \
    JOINT_COMMANDS_TOPIC, JOINT_STATES_TOPIC, MARKERS_TOPIC, METRICS_TOPIC, \
    ROBOT_DESCRIPTION_TOPIC, STATES_TOPIC, TF_STATIC_TOPIC, TF_TOPIC
from .pacing import Pacer, WindowStats
from .session import Due, Session
from .settings import BY_NAME, PARAMETERS, Settings
from .standard import StandardInterface
from .stopping import Stop, StopRequested
from ..cli import default_scene_path
from ..core import DivergenceError, SpecError
from ..scene import load_scene, SceneError
from ..urdf import prefixed_xml

#: The most steps one ~/step request may ask for (the node serves nothing else meanwhile).
MAX_STEPS_PER_REQUEST = 1_000_000
#: s of wall time between diagnostics (and the one-line summary in the log).
REPORT_PERIOD = 1.0
#: s of wall time the loop waits for events at most while paused (bounds shutdown latency).
IDLE_WAIT = 0.05
#: Events are served at most every SPIN_SHARE x the cost of one executor spin: rclpy's
#: spin_once walks every subscription and service (about 0.13 ms for a small scene, 2.8 ms
#: with 1000 wrench topics), so serving events after every step would cost more than the
#: physics in large scenes; this keeps event handling below 1 / SPIN_SHARE of the wall time.
SPIN_SHARE = 4.0
#: s of wall time the node lingers before it shuts down after a service reply: DDS sends a
#: reply asynchronously, and destroying the participant at once can drop it (seen under load:
#: ~/step interrupted by SIGTERM, its reply lost about 1 time in 5).
REPLY_GRACE = 0.5
#: s of wall time between looking up which per-body and reaction topics have subscribers.
AUDIENCE_REFRESH = 0.25
#: Per-body and per-constraint entities go without rclpy's default QoS-event handlers:
#: each adds waitables that every spin walks (measured: 5.7 ms vs 0.32 ms per spin_once
#: with 100 bodies).
QUIET_PUB = PublisherEventCallbacks(use_default_callbacks=False)
QUIET_SUB = SubscriptionEventCallbacks(use_default_callbacks=False)
#: robot_description (as robot_state_publisher offers it: the latest one to late joiners)
#: and /tf_static (as tf2_ros's StaticTransformBroadcaster offers it).
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
#: /tf as tf2_ros's TransformBroadcaster offers it.
TF_QOS = QoSProfile(depth=100, durability=DurabilityPolicy.VOLATILE,
                    reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


class SimNode(Node):
    """
    The simulation node: parameters, topics and services over one :class:`.Session`.

    Parameters
    ----------
    node_name : str
        As for :class:`rclpy.node.Node`.
    **kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``namespace``, ``parameter_overrides``).

    Raises
    ------
    SpecError, SceneError
        For an invalid parameter (named) or scene file.

    """

    def __init__(self, node_name: str = 'rigid_body_sim', **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        values = {}
        for p in PARAMETERS:
            descriptor = ParameterDescriptor(description=p.description, read_only=p.read_only,
                                             dynamic_typing=True)
            values[p.name] = self.declare_parameter(p.name, p.default, descriptor).value
        self.settings = Settings.from_values(values)
        s = self.settings
        scene_path = s.scene or str(default_scene_path())
        scene = load_scene(scene_path)
        self.session = Session(scene, s, node_name=self.get_fully_qualified_name())
        self.sim = scene.simulation
        self._paused = s.start_paused
        self._running = True
        self._pacer = Pacer(self.sim.dt, s.real_time_factor)
        self._window = WindowStats()
        self._overruns = 0        # total, before the current window
        self._spin_cost = 0.0     # s: running mean of a non-blocking executor spin
        self._audience: tuple = ([], [])   # per-body, reaction topics with subscribers
        self._audience_expires = 0.0
        self._last_logged: dict = {}   # Rejection -> monotonic time of its last log line
        self._last_reply = -np.inf     # monotonic time of the last service reply
        self.max_steps = MAX_STEPS_PER_REQUEST

        self._make_interfaces()
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.executor_ = SingleThreadedExecutor(context=self.context)
        self.executor_.add_node(self)
        scene_dt = self.session.scene_dt
        self.get_logger().info(
            f'scene {scene.name!r} ({scene_path}): {len(self.sim.bodies)} bodies, '
            f'{len(self.sim.constraint_names)} constraints, integrator '
            f'{self.sim.integrator_name}, physics {s.physics_rate:g} Hz (dt {self.sim.dt:g} s'
            + ('' if self.sim.dt == scene_dt
               else f"; the scene's dt {scene_dt:g} s is overridden") + '), publish '
            f'{s.publish_rate:g} Hz, real-time factor {s.real_time_factor:g}'
            + (', paused' if self._paused else ''))
        self._log_robots(scene)

    def _log_robots(self, scene) -> None:
        """Log the robots, what of them is not simulated, and which robot_description is."""
        models = self.sim.robots
        if not models:
            return
        listed = ', '.join(f'{m.spec.name!r} ({len(m.bodies)} moving bodies, '
                           f'{len(m.joints)} joints, {len(m.lumped)} lumped)' for m in models)
        self.get_logger().info(
            f'robots: {listed}; {len(self.sim.joint_names())} joints on {JOINT_STATES_TOPIC}, '
            + ('tf of every link' if self.settings.tf == 'links' else 'no tf (tf: off)'))
        for line in scene.warnings:   # (one line per robot)
            self.get_logger().warning(line)
        if len(models) > 1:
            self.get_logger().warning(
                f'{len(models)} robots: {ROBOT_DESCRIPTION_TOPIC} carries the first, '
                f'{models[0].spec.name!r}, only (one URDF per topic); not published there: '
                f'{[m.spec.name for m in models[1:]]}')

    # -- interfaces -----------------------------------------------------------------------

    def _make_interfaces(self) -> None:
        s = self.settings
        self._pubs: dict = {}   # private topic -> publisher, for every output topic
        self._wrench_subs = {}
        if s.per_body_topics:
            for name in self.sim.bodies.names:
                self._make_body_topics(name)
        for topic, msg_type in ((STATES_TOPIC, BodyStates), (METRICS_TOPIC, Metrics),
                                (MARKERS_TOPIC, MarkerArray)):
            self._pubs[topic] = self.create_publisher(msg_type, topic, 10)
        if self.sim.contact is not None:   # (a scene with collision shapes)
            self._pubs[CONTACTS_TOPIC] = self.create_publisher(Contacts, CONTACTS_TOPIC, 10)
        self._constraint_topics: set = set()
        self._sync_constraint_publishers()
        self._clock_pub = self.create_publisher(Clock, '/clock', 10)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._make_robot_interfaces()
        for srv_type, name, handler in (
                (Trigger, 'reset', self._on_reset), (SetBool, 'pause', self._on_pause),
                (Step, 'step', self._on_step),
                (AddConstraint, 'add_constraint', self._on_add_constraint),
                (RemoveConstraint, 'remove_constraint', self._on_remove_constraint)):
            service = self.create_service(srv_type, f'~/{name}',
                                          self._guarded(name, handler, srv_type))
            # Calls appear on ~/<name>/_service_event (request and response), so that a
            # recorded run holds its resets and constraint changes, as the runner's bags do.
            service.configure_introspection(self.get_clock(), qos_profile_services_default,
                                            ServiceIntrospectionState.CONTENTS)
        #: The ROS simulator interface (simulation_interfaces): services and an action.
        self.standard = StandardInterface(self)

    def _make_body_topics(self, name: str) -> None:
        """``~/bodies/<name>/pose`` and ``twist`` out, ``wrench`` in."""
        for kind, msg_type in (('pose', PoseStamped), ('twist', TwistStamped)):
            topic = body_topic(name, kind)
            self._pubs[topic] = self.create_publisher(msg_type, topic, 10,
                                                      event_callbacks=QUIET_PUB)
        self._wrench_subs[name] = self.create_subscription(
            WrenchStamped, body_topic(name, 'wrench'),
            lambda msg, body=name: self._on_wrench(body, msg), QoSProfile(depth=10),
            event_callbacks=QUIET_SUB)

    def _make_robot_interfaces(self) -> None:
        """joint_states, ~/joint_commands, <group>/commands (joints), robot_description, tf."""
        self._joint_pub = self._tf_pub = self._tf_static_pub = self._description_pub = None
        self._description_of = None   # the (prefix, URDF) robot_description carries
        self._tf_stamp_ns: Optional[int] = None   # of the last /tf message
        self._group_subs = {}
        self._sync_robot_interfaces()

    def _sync_robot_interfaces(self) -> None:
        """
        Make the robot interfaces the joints and robots there now need (after a spawn too).

        A group removed loses its subscription; joint_states and the tf publishers, once
        made, stay (a topic that goes quiet); /tf_static is published again for the
        robots there now, and robot_description when the first robot there changes (once
        every robot is deleted it keeps the last one's: an empty URDF would break its
        readers, robot_state_publisher and RViz).
        """
        if self.sim.joint_names() and self._joint_pub is None:
            self._joint_pub = self.create_publisher(JointState, JOINT_STATES_TOPIC, 10)
            self._joint_sub = self.create_subscription(
                JointState, JOINT_COMMANDS_TOPIC, self._on_joint_command, QoSProfile(depth=10))
        for group in set(self._group_subs) - set(self.session.groups):
            self.destroy_subscription(self._group_subs.pop(group))
        for group in self.session.groups:   # (forward_command_controller's topic and QoS)
            if group not in self._group_subs:
                self._group_subs[group] = self.create_subscription(
                    Float64MultiArray, group_topic(group),
                    lambda msg, group=group: self._on_group_command(group, msg),
                    QoSProfile(depth=10))
        robots = self.session.robots
        if robots and self._description_pub is None:
            self._description_pub = self.create_publisher(String, ROBOT_DESCRIPTION_TOPIC,
                                                          LATCHED)
        first = robots[0] if robots else None
        if first is not None and first is not self._description_of:
            # The first robot there is now (named as joint_states and /tf name them): a
            # late joiner gets the robot that exists.
            prefix, parsed = first
            self._description_pub.publish(String(data=prefixed_xml(parsed.xml, prefix)))
        self._description_of = first
        if robots and self.settings.tf == 'links' and self._tf_pub is None:
            self._tf_pub = self.create_publisher(TFMessage, TF_TOPIC, TF_QOS)
            self._tf_static_pub = self.create_publisher(TFMessage, TF_STATIC_TOPIC, LATCHED)
        if self._tf_static_pub is not None:
            self._publish_tf_static()

    def _guarded(self, name: str, handler, srv_type):
        """
        Wrap a service handler: an unexpected error is a refused request, not a crash.

        The error path cannot fail itself: it answers with a fresh response
        (whatever the handler left in its own), and each of its other steps
        (counting, logging, re-syncing the reaction publishers) is attempted on
        its own.
        """
        def serve(request, response):
            self.note_reply()
            try:
                return handler(request, response)
            except Exception as exc:  # noqa: B902 - no request may stop the node
                try:
                    text = repr(exc)
                except Exception:  # noqa: B902 - a repr that raises
                    text = type(exc).__name__
                reply = srv_type.Response()
                reply.success = False
                reply.message = f'internal error: {text} (the node runs on; nothing was ' \
                                f'changed unless the message says so; please report it)'
                for action in (
                        lambda: self.session.totals.reject(Rejection.INTERNAL_ERROR.value),
                        lambda: self.get_logger().error(f'~/{name}: internal error: {text}\n'
                                                        + traceback.format_exc()),
                        self._sync_constraint_publishers):
                    try:
                        action()
                    except Exception:  # noqa: B902 - the error path must not fail
                        pass
                return reply
        return serve

    def note_reply(self) -> None:
        """Note that a reply goes out now (the node lingers for it when it stops)."""
        self._last_reply = time.monotonic()   # (set before the reply goes out)

    def internal_error(self, name: str, exc: Exception, trace: str) -> None:
        """Count and log a request's unexpected error (its reply says so; the node runs on)."""
        for action in (lambda: self.session.totals.reject(Rejection.INTERNAL_ERROR.value),
                       lambda: self.get_logger().error(f'{name}: internal error: {exc!r}\n'
                                                       + trace),
                       self._sync_constraint_publishers):
            try:
                action()
            except Exception:  # noqa: B902 - the error path must not fail
                pass

    def _sync_constraint_publishers(self) -> None:
        """One ``~/constraints/<C>/wrench`` publisher per constraint present."""
        self._audience_expires = 0.0
        names = set(self.sim.constraint_names)
        for name in list(self._constraint_topics):
            if name not in names:
                self._drop_constraint_publisher(name)
        for name in self.sim.constraint_names:
            if name not in self._constraint_topics:
                self._add_constraint_publisher(name, self._new_constraint_publisher(name))

    def _new_constraint_publisher(self, name: str):
        """Create (not yet register) constraint ``name``'s reaction publisher."""
        return self.create_publisher(WrenchStamped, constraint_topic(name), 10,
                                     event_callbacks=QUIET_PUB)

    def _add_constraint_publisher(self, name: str, publisher) -> None:
        self._pubs[constraint_topic(name)] = publisher
        self._constraint_topics.add(name)
        self._audience_expires = 0.0

    def _drop_constraint_publisher(self, name: str) -> None:
        self._constraint_topics.discard(name)
        self._audience_expires = 0.0
        publisher = self._pubs.pop(constraint_topic(name), None)
        if publisher is not None:
            self.destroy_publisher(publisher)

    # -- inputs ---------------------------------------------------------------------------

    def _rejected(self, cause: Rejection, where: str, message: str) -> str:
        """Log a rejected input, at most once a second per cause; return the reply text."""
        text = f'{where}: rejected ({cause.value}): {message}'
        now = time.monotonic()
        if now - self._last_logged.get(cause, -np.inf) >= 1.0:
            self._last_logged[cause] = now
            self.get_logger().warning(text)
        return text

    def _reject(self, cause: Rejection, where: str, message: str) -> str:
        """Count and log a rejected service request; return the text for its reply."""
        self.session.totals.reject(cause.value)
        return self._rejected(cause, where, message)

    def _on_wrench(self, body: str, msg: WrenchStamped) -> None:
        if body not in self.sim.bodies.index:   # (a message for a body deleted meanwhile)
            return
        force, torque = conv.wrench_arrays(msg)
        try:
            self.session.queue_wrench(body, force, torque, msg.header.frame_id)
        except Rejected as exc:
            self._rejected(exc.cause, body_topic(body, 'wrench'), str(exc))

    def _on_joint_command(self, msg: JointState) -> None:
        names, positions, velocities, efforts = conv.joint_state_arrays(msg)
        try:
            self.session.queue_joint_command(names, positions, velocities, efforts)
        except Rejected as exc:
            self._rejected(exc.cause, JOINT_COMMANDS_TOPIC, str(exc))

    def _on_group_command(self, group: str, msg: Float64MultiArray) -> None:
        try:
            self.session.queue_group_command(group, conv.multi_array_values(msg))
        except Rejected as exc:
            self._rejected(exc.cause, group_topic(group), str(exc))

    # -- services -------------------------------------------------------------------------

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response):
        self.reset(state=True, clock=self.settings.reset_time, scene=True)
        self.standard.stopped = False
        response.success = True
        response.message = (f'reset to the initial state of the scene, stamped t = '
                            f'{self.session.seconds():.9g} s; applied wrenches cleared, '
                            f'constraints as in the scene'
                            + (', joint commands cleared' if self._joint_pub else '')
                            + (' (still paused)' if self._paused else ''))
        self.get_logger().info(response.message)
        return response

    def reset(self, state: bool, clock: bool, scene: bool = False) -> None:
        """
        Reset the scene (``state``: bodies, joints, constraints, wrenches) and/or the clock.

        ``clock``: the published clock restarts at 0. ``scene``: the scene as loaded
        (spawned bodies removed, deleted ones back). Then publish. ``~/reset``, the
        standard's ``reset_simulation`` and its STOPPED share it.
        """
        if state:
            before = list(self.sim.bodies.names)
            self.session.reset(time=clock, scene=scene)
            self.bodies_changed(before, scene=scene)
        elif clock:
            self.session.restart_clock()
        if clock:   # (a new epoch of stamps: its first /tf goes out even at a stamp seen)
            self._tf_stamp_ns = None
        now = time.perf_counter()
        self._pacer.restart(now)
        self._new_window(now)
        self._publish_clock()
        self._publish_now()

    def bodies_changed(self, before: list, markers: Optional[dict] = None,
                       scene: bool = False, robots: Optional[dict] = None) -> None:
        """
        Follow a change of bodies from ``before`` (names): topics, outputs, entities.

        Each body added gets its ``~/bodies/<B>/{pose,twist,wrench}``, each removed one
        loses them; the constraints' reaction publishers follow the constraints, the
        joints' and groups' topics the robots (``robots``: ``{name: (prefix,
        ParsedUrdf)}`` of those added). ``scene``: the scene as loaded is back
        (followed even with the same names).
        """
        now = list(self.sim.bodies.names)
        # (a robot fixed to the world with no moving link changes robots, not bodies)
        robots_now = [m.spec.name for m in self.sim.robots]
        robots_then = [m.spec.name for m in self.session.models]
        if now != before or scene or robots_now != robots_then:
            self.session.bodies_changed(markers, scene=scene, robots=robots)
            self._sync_robot_interfaces()
            if self.settings.per_body_topics:
                for name in set(before) - set(now):
                    for kind in ('pose', 'twist'):
                        self.destroy_publisher(self._pubs.pop(body_topic(name, kind)))
                    self.destroy_subscription(self._wrench_subs.pop(name))
                for name in now:
                    if name not in self._wrench_subs:
                        self._make_body_topics(name)
            self.standard.entities_changed()
            self._audience_expires = 0.0
        self._sync_constraint_publishers()

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response):
        diverged = self.session.diverged
        if not request.data and diverged:
            response.success = False
            response.message = self._reject(Rejection.DIVERGED, '~/pause',
                                            f'cannot resume after a divergence '
                                            f'({diverged}); call ~/reset')
            return response
        self.set_paused(bool(request.data))
        if not self._paused:
            self.standard.stopped = False
        response.success = True
        response.message = f'{"paused" if self._paused else "running"} at t = ' \
                           f'{self.session.seconds():.9g} s'
        return response

    def set_paused(self, paused: bool) -> None:
        """Pause or play (the pacing restarts from now on playing)."""
        was = self._paused
        self._paused = paused
        if was and not paused:
            self._pacer.restart(time.perf_counter())

    def _on_step(self, request: Step.Request, response: Step.Response):
        session = self.session
        response.time = session.stamp()
        response.step_count = session.step_count
        problem = None
        if not self._paused:
            problem = (Rejection.NOT_PAUSED, 'the simulation is running: pause it first '
                                             '(~/pause true)')
        elif session.diverged:
            problem = (Rejection.DIVERGED, f'{session.diverged}; call ~/reset')
        elif request.steps > self.max_steps:
            problem = (Rejection.BAD_STEP, f'steps: at most {self.max_steps} per '
                                           f'request, got {request.steps}')
        if problem:
            response.success = False
            response.message = self._reject(problem[0], '~/step', problem[1])
            return response
        done, failure = self.take_steps(request.steps)
        if done:
            self.standard.stopped = False
        response.time = session.stamp()
        response.step_count = session.step_count
        response.success = failure is None
        response.message = failure or f'{request.steps} steps to t = ' \
                                      f'{session.seconds():.9g} s'
        return response

    def take_steps(self, steps: int, publish: bool = True) -> tuple:
        """
        Take ``steps`` steps now (paused: no pacing) and publish the state after them.

        Returns ``(done, failure)``: the steps taken, and why they stopped early (None:
        they did not). A divergence or an internal error pauses the simulation and is
        named; so is a shutdown asked for meanwhile. ``publish`` False: only the outputs
        due on the way are published (the caller publishes the state when it pauses).
        """
        session = self.session
        due = None   # (0 steps: the current state is published)
        done, failure = 0, None
        for _ in range(steps):
            if not self._running:   # (SIGTERM or SIGINT ends a long request)
                failure = f'stopped after {done} of {steps} steps: the node is ' \
                          f'shutting down'
                break
            try:
                due = self._advance()
            except Exception as exc:  # noqa: B902 - reply, pause, say why
                due = None
                session.diverged = f'internal error in a step: {exc!r}'
                self._paused = True
                self.get_logger().error(f'paused: {session.diverged}\n'
                                        + traceback.format_exc())
            if session.diverged:
                failure = f'stopped after {done} of {steps} steps: ' \
                          f'{session.diverged}; call ~/reset'
                break
            done += 1
        if publish:   # the state after the last step: what that step did not publish
            self._publish_now(state=not (due and due.state), joints=not (due and due.joints),
                              tf=not (due and due.tf))
        return done, failure

    def _on_add_constraint(self, request: AddConstraint.Request,
                           response: AddConstraint.Response):
        # A transaction: check every field, create the reaction publisher, then add the
        # constraint; a failure at any point leaves the node as it was.
        where = f'~/add_constraint {shown(request.name)}'
        try:
            spec = self.session.check_constraint(request)
        except Rejected as exc:
            response.success = False
            response.message = self._rejected(exc.cause, where, str(exc))
            return response
        publisher = self._new_constraint_publisher(spec.name)
        try:
            rows = self.session.commit_constraint(spec)
        except Rejected as exc:
            self.destroy_publisher(publisher)
            response.success = False
            response.message = self._rejected(exc.cause, where, str(exc))
            return response
        except BaseException:
            self.destroy_publisher(publisher)
            raise
        self._add_constraint_publisher(spec.name, publisher)
        response.success = True
        response.rows_added = rows
        response.message = (f'added {request.type} constraint {request.name!r} ({rows} rows) '
                            f'at t = {self.session.seconds():.9g} s')
        self.get_logger().info(response.message)
        return response

    def _on_remove_constraint(self, request: RemoveConstraint.Request,
                              response: RemoveConstraint.Response):
        try:
            rows = self.session.remove_constraint(request.name)
        except Rejected as exc:
            response.success = False
            response.message = self._rejected(exc.cause, '~/remove_constraint', str(exc))
            return response
        self._drop_constraint_publisher(request.name)
        response.success = True
        response.rows_removed = rows
        response.message = f'removed constraint {request.name!r} ({rows} rows) at t = ' \
                           f'{self.session.seconds():.9g} s'
        self.get_logger().info(response.message)
        return response

    # -- parameters -----------------------------------------------------------------------

    def _check_parameters(self, params: list) -> SetParametersResult:
        try:
            trial = Settings(**vars(self.settings))
            trial.update({p.name: p.value for p in params if p.name in BY_NAME})
            self.session.check_settings(trial)   # (servo gains at the new dt, integrator)
        except SpecError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list) -> None:
        try:
            self._apply_checked_parameters(params)
        except Exception as exc:  # noqa: B902 - checked before: a bug, never a dead node
            self.session.totals.reject(Rejection.INTERNAL_ERROR.value)
            self.get_logger().error(f'applying parameters failed: {exc!r}\n'
                                    + traceback.format_exc())

    def _apply_checked_parameters(self, params: list) -> None:
        params = [p for p in params if p.name in BY_NAME]   # (not rclpy's use_sim_time, ...)
        if not params:
            return
        s = self.settings
        s.update({p.name: p.value for p in params})
        self.session.configure()
        if 'world_frame' in {p.name for p in params} and self._tf_static_pub is not None:
            self._publish_tf_static()   # (the latched one names the old world frame)
            self._tf_stamp_ns = None
        if {p.name for p in params} & {'physics_rate', 'real_time_factor'}:
            self._pacer.dt = self.sim.dt
            self._pacer.real_time_factor = s.real_time_factor
            self._pacer.restart(time.perf_counter())
        self.get_logger().info('parameters set: ' + ', '.join(
            f'{p.name} = {p.value!r}' for p in params))

    # -- stepping and output --------------------------------------------------------------

    def _advance(self) -> Optional[Due]:
        """Take one step and publish what is due; return what was (None: it diverged)."""
        t0 = time.perf_counter()
        try:
            due = self.session.advance()
        except DivergenceError as exc:
            self._paused = True
            self.get_logger().error(f'paused: {exc}; ~/reset recovers')
            self._publish_diagnostics(time.perf_counter())
            return None
        # (steps of ~/step while paused have no real-time budget)
        self._window.record_step(time.perf_counter() - t0,
                                 0.0 if self._paused else self._pacer.period)
        if due.clock:
            self._publish_clock()
        if due.state:
            self._publish_state()
        if due.joints:
            self._publish_joint_states()
        if due.tf:
            self._publish_tf()
        return due

    def _publish_clock(self) -> None:
        self._clock_pub.publish(Clock(clock=self.session.stamp()))

    def publish_now(self) -> None:
        """Publish the current state where subscribed (a state set between steps)."""
        self._publish_now()

    def _publish_now(self, state: bool = True, joints: bool = True, tf: bool = True) -> None:
        """Publish the current state (where subscribed): bodies, joints, tf."""
        if state:
            self._publish_state()
        if joints:
            self._publish_joint_states()
        if tf:
            self._publish_tf()

    def _publish_joint_states(self) -> None:
        """Publish joint_states (where subscribed): the joints now, stamped simulation time."""
        if self._joint_pub is not None and self._joint_pub.get_subscription_count() \
                and len(self.sim.joints):   # (quiet once every robot is deleted)
            self._joint_pub.publish(self.session.outputs.joint_states(self.session.stamp()))

    def _publish_tf(self) -> None:
        """
        Publish /tf: the world frame -> each robot body's frame, unless this stamp was.

        A second message with the stamp of the last (the state republished while
        paused, a ``~/step`` of 0 steps) would make every tf listener warn of
        repeated data (TF_REPEATED_DATA); the state at one stamp is one state.
        """
        if self._tf_pub is None:
            return
        stamp_ns = self.session.now_ns()
        if stamp_ns == self._tf_stamp_ns or not self._tf_pub.get_subscription_count():
            return
        self._tf_stamp_ns = stamp_ns
        self._tf_pub.publish(TFMessage(
            transforms=self.session.outputs.transforms(self.session.stamp())))

    def _publish_tf_static(self) -> None:
        """Publish /tf_static once (transient local: late listeners get it too)."""
        self._tf_static_pub.publish(TFMessage(
            transforms=self.session.outputs.static_transforms(self.session.stamp())))

    def _publish_state(self) -> None:
        """
        Publish poses, twists, body states, reactions, metrics, markers: where subscribed.

        A message nobody subscribes to is not built (per-body messages cost about
        35 us each from Python, a reaction solve more). Which per-body and reaction
        topics have subscribers is looked up every AUDIENCE_REFRESH seconds of wall
        time (asking 2000 publishers each time cost 5 ms a publish).
        """
        t0 = time.perf_counter()
        if t0 >= self._audience_expires:
            self._refresh_audience(t0)
        bodies, reactions = self._audience
        states, metrics, markers = (self._pubs[t].get_subscription_count() for t in
                                    (STATES_TOPIC, METRICS_TOPIC, MARKERS_TOPIC))
        contacts = CONTACTS_TOPIC in self._pubs and \
            self._pubs[CONTACTS_TOPIC].get_subscription_count()
        if not (bodies or reactions or states or metrics or markers or contacts):
            return
        for topic, msg in self.session.snapshot(bodies=bodies, states=bool(states),
                                                reactions=reactions, metrics=bool(metrics),
                                                markers=bool(markers), contacts=bool(contacts)):
            self._pubs[topic].publish(msg)
        self._window.record_publish(time.perf_counter() - t0)

    def _refresh_audience(self, now: float) -> None:
        """Find the per-body and reaction topics that have subscribers now."""
        pubs = self._pubs
        self._audience = (
            [i for i, name in enumerate(self.sim.bodies.names)
             if body_topic(name, 'pose') in pubs and (
                 pubs[body_topic(name, 'pose')].get_subscription_count()
                 or pubs[body_topic(name, 'twist')].get_subscription_count())],
            [name for name in self._constraint_topics
             if pubs[constraint_topic(name)].get_subscription_count()])
        self._audience_expires = now + AUDIENCE_REFRESH

    def _new_window(self, now: float) -> None:
        self._overruns += self._window.overruns
        self._window = WindowStats(wall_start=now, sim_start=self.session.seconds(),
                                   lag_resets_before=self._pacer.lag_resets,
                                   accuracy_misses_before=self.sim.accuracy().misses,
                                   capped_before=self.sim.work().get('capped_steps', 0),
                                   impacts_before=self._limit_impacts())

    def _limit_impacts(self) -> int:
        """Return the joint-limit impacts since the last reset (0 without limits)."""
        limits = self.sim.joint_limits()
        return limits['counters']['impacts'] if limits else 0

    def _publish_diagnostics(self, now: float) -> None:
        w = self._window
        wall = max(now - w.wall_start, 1e-9)
        session, sim = self.session, self.sim
        d = sim.diagnostics()
        work = sim.work()
        accuracy = d.accuracy
        rtf = (session.seconds() - w.sim_start) / wall
        level = DiagnosticStatus.OK
        summary = 'running'
        if session.diverged:
            level, summary = DiagnosticStatus.ERROR, f'diverged: {session.diverged}'
        elif self._paused:
            summary = 'paused'
        elif accuracy.misses > w.accuracy_misses_before:
            level, summary = DiagnosticStatus.WARN, \
                f'{accuracy.misses - w.accuracy_misses_before} steps missed the tolerance ' \
                f'{accuracy.tolerance:g} within {accuracy.budget} sub-steps'
        elif work.get('capped_steps', 0) > w.capped_before:
            level, summary = DiagnosticStatus.WARN, \
                f'{work["capped_steps"] - w.capped_before} steps hit the work bound of ' \
                f'{self.sim.integrator.max_substeps} sub-steps (a body turned by more than ' \
                f'{self.sim.integrator.max_rotation:g} rad in each: less accurate)'
        elif w.overruns or self._pacer.lag_resets > w.lag_resets_before:
            level, summary = DiagnosticStatus.WARN, f'{w.overruns} steps over budget, ' \
                f'{self._pacer.lag_resets - w.lag_resets_before} backlogs dropped'
        energy_change = d.total_energy - session.energy0
        # The largest force a joint carries now (N): what the joints do, in the log line.
        reaction_max = max((float(np.linalg.norm(r.force_world))
                            for per_body in sim.reactions().values()
                            for r in per_body.values()), default=0.0) \
            if sim.constraint_names and not session.diverged else 0.0
        values = {
            'sim_time_s': f'{session.seconds():.9g}',
            'time_since_reset_s': f'{sim.time:.9g}',
            'steps': str(session.step_count),
            'paused': str(self._paused).lower(),
            'integrator': sim.integrator_name,
            'dt_s': f'{sim.dt:.9g}',
            'physics_rate_target_hz': f'{self.settings.physics_rate:.6g}',
            'physics_rate_achieved_hz': f'{w.steps / wall:.6g}',
            'real_time_factor_target': f'{self.settings.real_time_factor:.6g}',
            'real_time_factor_achieved': f'{rtf:.6g}',
            'step_cost_mean_us': f'{(w.step_cost_sum / w.steps * 1e6) if w.steps else 0:.4g}',
            'step_cost_max_us': f'{w.step_cost_max * 1e6:.4g}',
            'publish_cost_mean_us':
                f'{(w.publish_cost_sum / w.publishes * 1e6) if w.publishes else 0:.4g}',
            'overruns_window': str(w.overruns),
            'overruns_total': str(self._overruns + w.overruns),
            'lag_resets_total': str(self._pacer.lag_resets),
            'lag_dropped_wall_s': f'{self._pacer.dropped_wall:.6g}',
            'energy_j': f'{d.total_energy:.12g}',
            'energy_change_j': f'{energy_change:.6g}',
            'constraint_violation': f'{d.constraint_violation:.3g}',
            'reaction_force_max_n': f'{reaction_max:.6g}',
            'substeps_total': str(work.get('substeps', 0)),
            'retries_total': str(work.get('retries', 0)),
            'capped_steps_total': str(work.get('capped_steps', 0)),
            'unconverged_projections_total': str(work.get('unconverged_projections', 0)),
            'tolerance': 'off' if accuracy.tolerance is None else f'{accuracy.tolerance:.3g}',
            'error_estimate': f'{accuracy.error_estimate:.3g}',
            'tolerance_substeps': str(accuracy.substeps),
            'tolerance_budget': str(accuracy.budget),
            'tolerance_misses_total': str(accuracy.misses),
            'wrench_messages_superseded': str(session.superseded),
        }
        if self._joint_pub is not None:
            counters = sim.joint_counters()
            values['joint_efforts_clamped'] = str(counters['clamped_efforts'])
            values['joint_velocity_limit_excursions'] = str(
                counters['velocity_limit_excursions'])
            values['joint_efforts_superseded'] = str(session.efforts_superseded)
            values['joint_targets_superseded'] = str(session.targets_superseded)
            values['group_commands_all_nan'] = str(session.group_noops)
            limits = sim.joint_limits()
            if limits:
                # Joints on a bound now, and what the limits did since the reset.
                values['joint_limits_active'] = ' '.join(
                    f'{joint}:{side}' for joint, side in limits['active'].items()) or 'none'
                c = limits['counters']
                values['joint_limit_impacts_total'] = str(c['impacts'])
                values['joint_limit_impacts_window'] = str(c['impacts'] - w.impacts_before)
                values['joint_limit_releases_total'] = str(c['releases'])
                values['joint_limit_excess_max'] = f'{c["max_violation"]:.3g}'
            friction = sim.joint_friction()
            if friction:
                values['joint_friction_sticking'] = ' '.join(friction['sticking']) or 'none'
                values['joint_friction_slips_total'] = str(friction['counters']['slips'])
            complementarity = sim.complementarity()
            if complementarity:
                values['joint_complementarity_force_excess_max'] = \
                    f'{complementarity["max_force_excess"]:.3g}'
                values['joint_complementarity_lcp_residual_max'] = \
                    f'{complementarity["lcp_residual_max"]:.3g}'
                values['joint_complementarity_lcp_failures_total'] = \
                    str(complementarity['lcp_failures'])
            saturation = sim.drive_saturation()
            if saturation:
                values['joint_drives_saturated'] = ' '.join(
                    f'{joint}:{"+" if sign > 0 else "-"}'
                    for joint, sign in saturation['saturated'].items()) or 'none'
                values['joint_drive_saturations_total'] = \
                    str(saturation['counters']['saturations'])
        contacts = sim.contacts()
        if contacts:
            # The latest step's contacts, and what contact did since the reset.
            c = contacts['counters']
            values['contacts'] = str(len(contacts['normal_force']))
            values['contact_depth_max_m'] = f'{float(np.max(contacts["depth"], initial=0.0)):.3g}'
            values['contact_depth_left_max_m'] = f'{c["max_depth"]:.3g}'
            values['contact_depth_end_max_m'] = f'{c["end_depth"]:.3g}'
            values['contact_complementarity_residual_max'] = f'{c["complementarity_max"]:.3g}'
            values['contact_lcp_iterations_max'] = str(c['lcp_iterations_max'])
            values['contact_lcp_failures_total'] = str(c['lcp_failures'])
            values['contact_lcp_solves_total'] = str(c['lcp_solves'])
            values['contact_lcp_newton_total'] = str(c['lcp_newton'])
            values['contact_lcp_pivoted_total'] = str(c['lcp_pivoted'])
            values['contact_lcp_sparse_total'] = str(c['lcp_sparse'])
            values['contact_lcp_pgs_total'] = str(c['lcp_pgs'])
            values['contact_impacts_total'] = str(c['impacts'])
            values['contact_events_capped_total'] = str(c['events_capped'])
            values['contact_compiled_steps_total'] = str(c['compiled_steps'])
        rejected = session.totals.rejected
        for cause in Rejection:
            values[f'rejected_{cause.value}'] = str(rejected.get(cause.value, 0))
        # Named by the fully qualified node name: two namespaced simulators' statuses
        # stay apart in a diagnostic aggregator. Stamped with simulation time, as every
        # header the node publishes.
        status = DiagnosticStatus(level=level,
                                  name=f'{self.get_fully_qualified_name()}: physics',
                                  message=summary, hardware_id=self.get_fully_qualified_name(),
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        stamp = session.stamp()
        self._diag_pub.publish(DiagnosticArray(header=Header(stamp=stamp), status=[status]))
        self.get_logger().info(
            f't={session.seconds():.3f} s  rtf={rtf:.2f}  {w.steps / wall:.0f} steps/s  '
            f'E={d.total_energy:.6g} J  dE={energy_change:+.1e} J  '
            + (f'violation={d.constraint_violation:.1e}  reaction_max={reaction_max:.3g} N'
               if sim.constraint_names else '')
            + ('  ' if sim.constraint_names and contacts else '')
            + (f'contacts={len(contacts["normal_force"])}  '
               f'depth_end_max={contacts["counters"]["end_depth"]:.1e} m'
               if contacts else '')
            + (f'  overruns={w.overruns}' if w.overruns else '') + f'  [{summary}]')
        self._new_window(now)

    # -- the loop -------------------------------------------------------------------------

    def stop(self) -> None:
        """Ask the loop to end (safe from a signal handler)."""
        self._running = False

    def linger(self) -> None:
        """Wait until the last service reply is REPLY_GRACE old, so that it can arrive."""
        remaining = self._last_reply + REPLY_GRACE - time.monotonic()
        if remaining > 0.0:
            time.sleep(remaining)

    def run(self) -> None:
        """Step at the physics rate, paced to the wall clock, until :meth:`stop`."""
        now = time.perf_counter()
        self._pacer.restart(now)
        self._new_window(now)
        self._publish_clock()
        self._publish_now()
        next_report = next_republish = now + REPORT_PERIOD
        last_spin = now
        while self._running and rclpy.ok(context=self.context):
            now = time.perf_counter()
            if now >= next_report:
                self._publish_diagnostics(now)
                next_report += REPORT_PERIOD
                if next_report < now:
                    next_report = now + REPORT_PERIOD
            if self._paused:
                if now >= next_republish:
                    # Late subscribers see a paused simulation too (same stamp again).
                    self._publish_clock()
                    self._publish_now()
                    next_republish = now + REPORT_PERIOD
                self._spin(IDLE_WAIT)
                last_spin = time.perf_counter()
                continue
            next_republish = now + REPORT_PERIOD
            events_due = now - last_spin >= SPIN_SHARE * self._spin_cost
            if self._pacer.due(now):
                try:
                    self._advance()
                except Exception as exc:  # noqa: B902 - keep serving; pause and say why
                    self.session.diverged = f'internal error in a step: {exc!r}'
                    self._paused = True
                    self.get_logger().error(f'paused: {self.session.diverged}\n'
                                            + traceback.format_exc())
                self._pacer.stepped()
                if events_due:
                    self._spin(0.0)
                    last_spin = time.perf_counter()
                continue
            wait = min(self._pacer.next_due() - now, IDLE_WAIT)
            if events_due:
                self._spin(wait)
                last_spin = time.perf_counter()
            else:
                time.sleep(wait)

    def _spin(self, timeout: float) -> None:
        """Serve ready callbacks (one); learn what a spin costs from the non-blocking ones."""
        t0 = time.perf_counter()
        if self.standard.wake():   # (a running action goes on at this spin: no waiting)
            timeout = 0.0
        try:
            self.executor_.spin_once(timeout_sec=timeout)
        except Exception as exc:  # noqa: B902 - a message or parameter callback's bug
            self.session.totals.reject(Rejection.INTERNAL_ERROR.value)
            self.get_logger().error(f'a callback failed: {exc!r}\n' + traceback.format_exc())
        if timeout == 0.0:
            self._spin_cost = 0.8 * self._spin_cost + 0.2 * (time.perf_counter() - t0)


def _use_service_profile() -> None:
    """Load config/fastdds_services.xml unless the user chose a Fast DDS profile file."""
    if os.environ.get('FASTDDS_DEFAULT_PROFILES_FILE') or \
            os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE'):
        return
    profile = default_scene_path().parent / 'fastdds_services.xml'
    if profile.is_file():   # (Fast DDS 2.x, Jazzy's, reads the FASTRTPS_ name)
        os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)


def main(args: Optional[list] = None, stop: Optional[Stop] = None) -> int:
    """
    Run the node until SIGINT or SIGTERM; exit code 0, or 2 for a bad parameter or scene.

    ``stop``: the signal handling the console script installed before importing
    this module (:mod:`.entry`); without it, it is installed here.
    """
    stop = stop if stop is not None else Stop().install()
    node = None
    try:
        _use_service_profile()
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        try:
            node = SimNode()
        except SceneError as exc:
            print(f'rigid_body_sim: error: scene: {exc}', file=sys.stderr)
            return 2
        except SpecError as exc:
            print(f'rigid_body_sim: error: {exc}', file=sys.stderr)
            return 2
        stop.on_stop(node.stop)   # from here on a signal stops the loop
        node.run()
        node.get_logger().info('shutting down')
        node.standard.finish()   # (a running simulate_steps goal gets its answer)
        node.linger()
        return 0
    except StopRequested:
        print('sim_node: stopped while starting', file=sys.stderr, flush=True)
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
