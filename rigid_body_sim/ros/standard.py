"""
The ROS simulator interface (``simulation_interfaces`` 1.0.0) on the node.

Services and the action live under the node's namespace with relative names, as Gazebo
serves them (``/get_simulation_state`` for a node in ``/``); each request gets a
reply whose ``result`` says what happened, and a refused request changes nothing.

- ``get_simulator_features``: exactly what works (:data:`FEATURES`).
- ``get_simulation_state`` / ``set_simulation_state``: STOPPED (paused at the scene's
  start: a reset of everything, time included), PLAYING, PAUSED, QUITTING (the node
  replies, then shuts down). A stopped simulation may be played or paused (the state
  message's own rule); asking for the state it is in answers ALREADY_IN_TARGET_STATE;
  playing a diverged simulation STATE_TRANSITION_ERROR (reset it first); a state that
  does not exist INCORRECT_TRANSITION.
- ``reset_simulation``: SCOPE_TIME restarts the published clock at 0 with the bodies
  where they are; SCOPE_STATE puts the scene back to its start (bodies, joints,
  constraints, applied wrenches; as ``~/reset``) with the clock running on; both, or
  SCOPE_ALL / SCOPE_DEFAULT, do both (the scene as loaded: spawned entities gone,
  deleted ones back); SCOPE_SPAWNED removes spawned entities. The play state is kept.
- ``step_simulation`` and the ``simulate_steps`` action (feedback after every step,
  cancellable between steps): while paused (or stopped) only; while playing they answer
  RESULT_INCORRECT_STATE (the Result message's own example; the two files' comments
  say OPERATION_FAILED).
- ``get_entities`` / ``get_entities_states`` (a regular expression searched in the
  name, categories, and a region the entity's bounds overlap: a sphere, a box or a
  convex hull; a tags filter is not supported: entities have no tags), ``get_entity_state``,
  ``set_entity_state`` (in the header's frame: the world (empty or the node's
  ``world_frame``), an entity's, a body's or a robot link's, where it is now; the
  acceleration given is ignored: it follows from the forces; states read are in the
  world frame),
  ``get_entity_info``, ``get_entity_bounds`` (a box about the entity's frame from its
  shapes): see :mod:`.entities` for what an entity is. An unknown entity answers
  RESULT_NOT_FOUND.
- ``spawn_entity``: a robot (URDF or xacro: a file at ``uri``, plain, ``file://`` or
  ``package://``, or the document in ``resource_string``; or our YAML robot entry with
  its command groups), or one body (our YAML body entry); names as asked, or free ones
  with ``allow_renaming`` (a robot whose links or joints are taken gets the prefix
  ``<name>_``); the initial pose in its header's frame (as set_entity_state's).
  ``delete_entity``: a body or a robot, with the constraints that held it (named in the
  reply).
- ``set_entity_info``, ``get_named_poses``, ``get_named_pose_bounds``,
  ``get_spawnables``: served, answering RESULT_FEATURE_UNSUPPORTED (not in the features).

Our own ``~/reset``, ``~/pause`` and ``~/step`` share these implementations.
"""

from __future__ import annotations

from dataclasses import replace
import math
from pathlib import Path
import time
import traceback
from typing import Any

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.qos import qos_profile_services_default
from rclpy.service_introspection import ServiceIntrospectionState
from rclpy.task import Future
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Bounds, EntityInfo, Result, SimulationState, \
    SimulatorFeatures
from simulation_interfaces.srv import DeleteEntity, GetEntities, GetEntitiesStates, \
    GetEntityBounds, GetEntityInfo, GetEntityState, GetNamedPoseBounds, GetNamedPoses, \
    GetSimulationState, GetSimulatorFeatures, GetSpawnables, ResetSimulation, SetEntityInfo, \
    SetEntityState, SetSimulationState, SpawnEntity, StepSimulation
from std_msgs.msg import Header
import yaml

from . import conversions as conv
from .entities import Entities, EntityError, ROBOT
from .inputs import check_name_token
from .outputs import body_topic, constraint_topic, group_topic
from ..core import rotation as so3
from ..core import SpecError
from ..scene import body_from_dict, robot_from_dict
from ..urdf import read_robot_xml, UrdfError

F = SimulatorFeatures
#: What this node implements of the standard (GetSimulatorFeatures).
FEATURES = (F.SPAWNING, F.DELETING, F.SPAWNING_RESOURCE_STRING,
            F.ENTITY_BOUNDS, F.ENTITY_BOUNDS_BOX, F.ENTITY_BOUNDS_CONVEX,
            F.ENTITY_CATEGORIES, F.ENTITY_STATE_GETTING,
            F.ENTITY_STATE_SETTING, F.ENTITY_INFO_GETTING, F.SIMULATION_RESET,
            F.SIMULATION_RESET_TIME, F.SIMULATION_RESET_STATE, F.SIMULATION_RESET_SPAWNED,
            F.SIMULATION_STATE_GETTING,
            F.SIMULATION_STATE_SETTING, F.SIMULATION_STATE_PAUSE, F.STEP_SIMULATION_SINGLE,
            F.STEP_SIMULATION_MULTIPLE, F.STEP_SIMULATION_ACTION)
CUSTOM_INFO = ('rigid_body_sim: exact multipliers (joints, limits, contact), every '
               "service of simulation_interfaces 1.0.0 answers; entities are the scene's "
               "bodies and robots (a robot's state is its base link's); spawn formats: "
               "'urdf' and 'xacro' (a robot: a file at uri, or the document in "
               "resource_string), 'yaml' (one body as a scene's bodies: entry, or one robot "
               'as a robots: entry with its command_groups); see docs/node.md')
#: What spawn_entity takes: a URDF or xacro robot, or our YAML (a scene's ``bodies:`` or
#: ``robots:`` entry).
SPAWN_FORMATS = ['urdf', 'xacro', 'yaml']
S = SimulationState
STATE_NAMES = {S.STATE_STOPPED: 'STOPPED', S.STATE_PLAYING: 'PLAYING',
               S.STATE_PAUSED: 'PAUSED', S.STATE_QUITTING: 'QUITTING'}
#: s of wall time a running action steps in one loop turn before the node serves requests.
ACTION_SLICE = 0.01
R = ResetSimulation.Request
#: The scope bits the standard defines (SCOPE_ALL sets every bit).
SCOPE_BITS = R.SCOPE_TIME | R.SCOPE_STATE | R.SCOPE_SPAWNED
CODES = {'NOT_FOUND': Result.RESULT_NOT_FOUND,
         'OPERATION_FAILED': Result.RESULT_OPERATION_FAILED,
         'INCORRECT_STATE': Result.RESULT_INCORRECT_STATE,
         'FEATURE_UNSUPPORTED': Result.RESULT_FEATURE_UNSUPPORTED}


def resolve_uri(uri: str) -> Path:
    """
    Return the file a spawn ``uri`` names: a path, ``file://`` a path, ``package://P/rest``.

    A package is looked up in the ament index (its share folder); EntityError
    (MISSING_ASSETS) if it is not found.
    """
    if uri.startswith('file://'):
        return Path(uri[len('file://'):])
    if uri.startswith('package://'):
        package, _, rest = uri[len('package://'):].partition('/')
        try:
            from ament_index_python.packages import get_package_share_directory
            return Path(get_package_share_directory(package)) / rest
        except Exception as exc:  # noqa: B902 - no index, or no such package
            raise EntityError('MISSING_ASSETS', f'uri: {uri!r}: package {package!r} not '
                                                f'found ({type(exc).__name__})') from None
    return Path(uri)


def uri_format(path: Path) -> Any:
    """Return ``'yaml'``, ``'urdf'`` or ``'xacro'`` by a file's suffix (None: not served)."""
    suffix = path.suffix.lower()
    return {'.yaml': 'yaml', '.yml': 'yaml', '.urdf': 'urdf', '.xacro': 'xacro'}.get(suffix)


def expand_xacro(text: str) -> str:
    """Return the URDF of a xacro document given as text (EntityError if xacro fails)."""
    import tempfile
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'resource.urdf.xacro'
        path.write_text(text)
        try:
            return read_robot_xml(path)
        except UrdfError as exc:
            raise EntityError('RESOURCE_PARSE_ERROR', f'resource: {exc}') from None


def result(code: int = Result.RESULT_OK, message: str = '') -> Result:
    """Return a Result of ``code`` and ``message``."""
    return Result(result=code, error_message=message)


class StandardInterface:
    """
    The services and the action of ``simulation_interfaces`` on a :class:`.node.SimNode`.

    The node keeps the play state (``_paused``); this adds STOPPED (paused at the start,
    until a step, a play or a state set) and QUITTING.
    """

    def __init__(self, node: Any) -> None:
        self.node = node
        self.entities = Entities(node.sim)
        self.stopped = False
        self.quitting = False
        self._wake: list = []   # futures of running actions, woken between loop turns
        #: Counts resets, STOPPED and QUITTING: a running action ends when it changes.
        self.generation = 0
        self._running_goal = None
        for srv_type, name, handler in (
                (GetSimulatorFeatures, 'get_simulator_features', self._features),
                (GetSimulationState, 'get_simulation_state', self._get_state),
                (SetSimulationState, 'set_simulation_state', self._set_state),
                (ResetSimulation, 'reset_simulation', self._reset),
                (StepSimulation, 'step_simulation', self._step),
                (GetEntities, 'get_entities', self._get_entities),
                (GetEntitiesStates, 'get_entities_states', self._get_entities_states),
                (GetEntityState, 'get_entity_state', self._get_entity_state),
                (SetEntityState, 'set_entity_state', self._set_entity_state),
                (GetEntityInfo, 'get_entity_info', self._get_entity_info),
                (GetEntityBounds, 'get_entity_bounds', self._get_entity_bounds),
                (SpawnEntity, 'spawn_entity', self._spawn),
                (DeleteEntity, 'delete_entity', self._delete),
                (SetEntityInfo, 'set_entity_info', self._unsupported('setting entity info')),
                (GetNamedPoses, 'get_named_poses', self._unsupported('named poses')),
                (GetNamedPoseBounds, 'get_named_pose_bounds',
                 self._unsupported('named poses')),
                (GetSpawnables, 'get_spawnables', self._unsupported('spawnables'))):
            service = node.create_service(srv_type, name, self._guarded(name, handler,
                                                                        srv_type))
            service.configure_introspection(node.get_clock(), qos_profile_services_default,
                                            ServiceIntrospectionState.CONTENTS)
        # One goal at a time: a second is rejected while one runs (their steps would
        # interleave on one clock).
        self.action = ActionServer(node, SimulateSteps, 'simulate_steps',
                                   execute_callback=self._simulate,
                                   goal_callback=lambda goal: GoalResponse.REJECT
                                   if self._running_goal is not None else GoalResponse.ACCEPT,
                                   cancel_callback=lambda handle: CancelResponse.ACCEPT)

    # -- plumbing -------------------------------------------------------------------------

    def _guarded(self, name: str, handler, srv_type):
        """Wrap a handler: an unexpected error is a RESULT_OPERATION_FAILED reply, not a crash."""
        def serve(request, response):
            self.node.note_reply()
            try:
                return handler(request, response)
            except Exception as exc:  # noqa: B902 - no request may stop the node
                reply = srv_type.Response()
                if hasattr(reply, 'result'):
                    reply.result = result(Result.RESULT_OPERATION_FAILED,
                                          f'internal error: {exc!r} (the node runs on; '
                                          f'please report it)')
                self.node.internal_error(name, exc, traceback.format_exc())
                return reply
        return serve

    def _unsupported(self, what: str):
        def handler(request, response):
            response.result = result(Result.RESULT_FEATURE_UNSUPPORTED,
                                     f'{what} is not supported by rigid_body_sim yet; see '
                                     f'get_simulator_features')
            return response
        return handler

    def wake(self) -> bool:
        """Let a running action go on (the node calls it between loop turns); tell if one does."""
        wake, self._wake = self._wake, []
        for future in wake:
            future.set_result(None)
        return bool(wake)

    def finish(self, grace: float = 0.25) -> None:
        """
        Let a running action end and answer before the node shuts down (QUITTING, a signal).

        Its goal is aborted (the generation changes), then requests are served for
        ``grace`` s more (a client asking for the result now).
        """
        if self._running_goal is None:
            return
        self.generation += 1
        end = time.monotonic() + 1.0
        while self._running_goal is not None and time.monotonic() < end:
            self.wake()
            self.node.executor_.spin_once(timeout_sec=0.05)
        end = time.monotonic() + grace
        while time.monotonic() < end:
            self.node.executor_.spin_once(timeout_sec=0.05)

    def header(self) -> Header:
        """Return a header at the published time in the world frame."""
        return Header(stamp=self.node.session.stamp(),
                      frame_id=self.node.settings.world_frame)

    def state(self) -> int:
        """Return the SimulationState now."""
        if self.quitting:
            return S.STATE_QUITTING
        if self.stopped:
            return S.STATE_STOPPED
        return S.STATE_PAUSED if self.node._paused else S.STATE_PLAYING

    # -- the simulation -------------------------------------------------------------------

    def _features(self, request, response):
        response.features = SimulatorFeatures(features=list(FEATURES),
                                              spawn_formats=list(SPAWN_FORMATS),
                                              custom_info=CUSTOM_INFO)
        return response

    def _get_state(self, request, response):
        response.state = SimulationState(state=self.state())
        response.result = result()
        return response

    def _set_state(self, request, response):
        target, now = request.state.state, self.state()
        Set = SetSimulationState.Response
        if target not in STATE_NAMES:
            response.result = result(Set.INCORRECT_TRANSITION,
                                     f'state.state: no state {target}; states: '
                                     f'{sorted(STATE_NAMES.items())}')
            return response
        if target == now:
            response.result = result(Set.ALREADY_IN_TARGET_STATE,
                                     f'already {STATE_NAMES[now]}')
            return response
        node = self.node
        if target == S.STATE_QUITTING:
            self.quitting = True
            self.generation += 1
            node._paused = True
            node.stop()   # (the loop ends; the node lingers for this reply to go out)
            response.result = result(message='quitting')
            return response
        if target == S.STATE_PLAYING:
            if node.session.diverged:
                response.result = result(Set.STATE_TRANSITION_ERROR,
                                         f'cannot play: {node.session.diverged}; reset it '
                                         f'(reset_simulation)')
                return response
            node.set_paused(False)
        elif target == S.STATE_PAUSED:
            node.set_paused(True)
        else:   # STOPPED: pause and reset everything, the clock to 0
            node.set_paused(True)
            node.reset(state=True, clock=True, scene=True)
            self.generation += 1
            self.stopped = True
            response.result = result(message="stopped: paused at the scene's start, t = 0")
            return response
        self.stopped = False
        response.result = result(message=f'{STATE_NAMES[now]} -> {STATE_NAMES[target]}')
        return response

    def _reset(self, request, response):
        scope = request.scope
        if scope in (R.SCOPE_DEFAULT, R.SCOPE_ALL):
            scope = SCOPE_BITS
        if scope & ~SCOPE_BITS:
            response.result = result(Result.RESULT_OPERATION_FAILED,
                                     f'scope: {request.scope} sets bits the standard does not '
                                     f'define (TIME 1, STATE 2, SPAWNED 4, ALL 255)')
            return response
        done = []
        node = self.node
        if scope & R.SCOPE_SPAWNED and scope != SCOPE_BITS:
            before = list(node.sim.bodies.names)
            gone = node.sim.remove_spawned()
            node.bodies_changed(before)
            node.publish_now()
            done.append(f'spawned entities removed: {gone}')
        if scope & (R.SCOPE_STATE | R.SCOPE_TIME):
            # Every bit: the scene as loaded (deleted bodies back, spawned ones gone).
            node.reset(state=bool(scope & R.SCOPE_STATE), clock=bool(scope & R.SCOPE_TIME),
                       scene=scope == SCOPE_BITS)
            done += [what for bit, what in ((R.SCOPE_STATE, "the scene's start state"),
                                            (R.SCOPE_TIME, 'the clock to 0')) if scope & bit]
            if scope == SCOPE_BITS:
                done.append('the scene as loaded')
        self.generation += 1
        # Still STOPPED (paused at the start, t = 0) unless the state alone was reset
        # (its clock runs on).
        self.stopped = self.stopped and not (scope & R.SCOPE_STATE and not scope & R.SCOPE_TIME)
        response.result = result(message='reset: ' + ', '.join(done)
                                 + f'; t = {self.node.session.seconds():.9g} s')
        return response

    def _step(self, request, response):
        problem = self.step_problem(request.steps)
        if problem:
            response.result = result(*problem)
            return response
        done, failure = self.node.take_steps(request.steps)
        self.stopped = self.stopped and done == 0
        response.result = result(Result.RESULT_OPERATION_FAILED, failure) if failure else \
            result(message=f'{done} steps to t = {self.node.session.seconds():.9g} s')
        return response

    def step_problem(self, steps: int):
        """Return ``(code, message)`` when steps cannot be taken now (None: they can)."""
        node = self.node
        if not node._paused:
            return (Result.RESULT_INCORRECT_STATE, 'the simulation is playing: pause it first '
                                                   '(set_simulation_state PAUSED)')
        if node.session.diverged:
            return (Result.RESULT_OPERATION_FAILED, f'{node.session.diverged}; reset it '
                                                    f'(reset_simulation)')
        if steps > node.max_steps:
            return (Result.RESULT_OPERATION_FAILED, f'steps: at most {node.max_steps} per '
                                                    f'request, got {steps}')
        return None

    async def _simulate(self, goal_handle):
        """
        Take the goal's steps with feedback after each; end on a cancel or a problem.

        Steps are taken for up to :data:`ACTION_SLICE` s of wall time a loop turn; between
        turns the node serves other requests (a cancel, a reset, a play).
        """
        self._running_goal = goal_handle
        try:
            return await self._run_goal(goal_handle)
        finally:
            self._running_goal = None

    async def _run_goal(self, goal_handle):
        steps = goal_handle.request.steps
        out = SimulateSteps.Result()
        done, generation = 0, self.generation
        problem = self.step_problem(steps)
        turn = time.perf_counter()
        while problem is None and done < steps:
            if goal_handle.is_cancel_requested:
                goal_handle.canceled()
                out.result = result(message=f'canceled after {done} of {steps} steps')
                return out
            taken, failure = self.node.take_steps(1, publish=False)
            done += taken
            self.stopped = self.stopped and done == 0
            if failure:
                problem = (Result.RESULT_OPERATION_FAILED,
                           f'after {done} of {steps} steps: {failure}')
                break
            goal_handle.publish_feedback(SimulateSteps.Feedback(completed_steps=done,
                                                                remaining_steps=steps - done))
            if done < steps and time.perf_counter() - turn >= ACTION_SLICE:
                self.node.publish_now()   # (the state where it pauses for a turn)
                future = Future()
                self._wake.append(future)
                await future   # (the node serves other requests, and cancels, meanwhile)
                turn = time.perf_counter()
                problem = self.step_problem(steps - done)
            if problem is None and self.generation != generation:
                problem = (Result.RESULT_OPERATION_FAILED,
                           f'after {done} of {steps} steps: the simulation was reset, '
                           f'stopped or is quitting')
        self.node.publish_now()   # (the state after its last step)
        if problem is not None:
            goal_handle.abort()
            out.result = result(*problem)
            return out
        goal_handle.succeed()
        out.result = result(message=f'{done} steps to t = {self.node.session.seconds():.9g} s')
        return out

    # -- spawning and deleting -----------------------------------------------------------

    def entities_changed(self) -> None:
        """Follow bodies added or removed."""
        self.entities = Entities(self.node.sim)

    def _spawn(self, request, response):
        """Spawn a body (our YAML) or a robot (URDF, xacro, or our YAML robot entry)."""
        Sp = SpawnEntity.Response
        node = self.node
        try:
            kind, made = self._spawned_entity(request)
        except EntityError as exc:
            response.result = result(getattr(Sp, exc.code, CODES.get(exc.code)), str(exc))
            return response
        before = list(node.sim.bodies.names)
        try:
            if kind == 'body':
                body, shapes, marker = made
                node.sim.add_body(body, shapes)
                name, what = body.name, f'{len(shapes)} shapes'
            else:
                spec, parsed, groups = made
                node.sim.add_robot(spec, groups)
                model = node.sim.robots[-1]
                name, what = spec.name, (f'robot: {len(model.bodies)} bodies, '
                                         f'{len(model.joints)} joints')
        except SpecError as exc:
            code = Sp.INVALID_POSE if 'would overlap' in exc.problem else (
                Sp.NAME_NOT_UNIQUE if 'is taken' in exc.problem or 'constraints named'
                in exc.problem else Sp.RESOURCE_PARSE_ERROR)
            response.result = result(code, str(exc))
            return response
        try:
            if kind == 'body':
                node.bodies_changed(before, {body.name: marker} if marker else None)
            else:
                node.bodies_changed(before, robots={spec.name: (spec.prefix, parsed)})
        except BaseException:   # (its topics failed: it goes again, nothing else changed)
            node.sim.remove_body(name) if kind == 'body' else node.sim.remove_robot(name)
            node.bodies_changed(list(node.sim.bodies.names) + ['?'])
            raise
        self.stopped = False
        node.publish_now()
        response.entity_name = self.entities.entity_of(name, kind == 'robot')
        response.result = result(message=f'spawned {response.entity_name!r} ({what}) at '
                                         f't = {node.session.seconds():.9g} s')
        return response

    def _spawned_entity(self, request) -> tuple:
        """
        Return what a spawn request makes: a body or a robot, by the resource's format.

        ``('body', (RigidBody, shapes, marker))`` or ``('robot', (RobotSpec, ParsedUrdf,
        groups))``; EntityError (a code) if refused.
        """
        text, folder, fmt = request.resource_string, Path('.'), None
        if not text and not request.uri:
            raise EntityError('NO_RESOURCE', 'uri and resource_string are both empty')
        if request.entity_namespace:
            raise EntityError('FEATURE_UNSUPPORTED', 'entity_namespace: entities are not '
                                                     'put in namespaces here (leave it empty; '
                                                     "a robot's prefix: a YAML robot entry)")
        if request.uri:   # (the standard: a uri, when given, wins over resource_string)
            path = resolve_uri(request.uri)
            fmt = uri_format(path)
            if fmt is None:
                raise EntityError('UNSUPPORTED_FORMAT', f'uri: {request.uri!r}: formats: '
                                                        f'{SPAWN_FORMATS} (.yaml, .yml, '
                                                        f'.urdf, .xacro)')
            if not path.is_file():
                raise EntityError('RESOURCE_PARSE_ERROR', f'uri: {request.uri!r}: no such '
                                                          f'file ({path})')
            folder = path.parent
            if fmt == 'yaml':
                try:
                    text = path.read_text()
                except (OSError, UnicodeDecodeError) as exc:
                    raise EntityError('RESOURCE_PARSE_ERROR', f'uri: {exc}') from None
        elif text.lstrip().startswith('<'):
            if '<sdf' in text[:2000]:
                raise EntityError('UNSUPPORTED_FORMAT', f'resource: SDFormat is not read; '
                                                        f'formats: {SPAWN_FORMATS}')
            fmt = 'xacro' if 'xmlns:xacro' in text[:5000] else 'urdf'
        else:
            fmt = 'yaml'
        if fmt == 'yaml':
            try:
                data = yaml.safe_load(text)
            except yaml.YAMLError as exc:
                raise EntityError('RESOURCE_PARSE_ERROR', f'resource: not YAML: {exc}') from None
            if not isinstance(data, dict):
                raise EntityError('RESOURCE_PARSE_ERROR', f'resource: expected one body (a '
                                                          f"scene's bodies: entry) or one robot "
                                                          f'(a robots: entry) as a mapping, got '
                                                          f'{data!r}'[:300])
            if 'urdf' in data:
                return 'robot', self._spawned_robot(request, dict(data), folder, None)
            return 'body', self._spawned_body(request, dict(data), folder)
        if request.uri:
            entry = {'urdf': str(path.resolve())}
            xml = None
        else:
            entry = {'urdf': '<resource_string>'}
            xml = text if fmt == 'urdf' else expand_xacro(text)
        return 'robot', self._spawned_robot(request, entry, folder, xml)

    def _free_name(self, request, name: Any, taken: set) -> str:
        """Return the entity's name: as asked, or (allow_renaming) a free one; EntityError."""
        if not isinstance(name, str) or not name or name in taken:
            if not request.allow_renaming:
                raise EntityError('NAME_NOT_UNIQUE' if name else 'NAME_INVALID',
                                  f'name: {name!r} is taken (allow_renaming gives it a free '
                                  f'one)' if name else 'name: empty, in the request and the '
                                                       'resource (allow_renaming generates one)')
            # A free name: the given one (or 'entity') and a number, kept a name token.
            base = name if isinstance(name, str) and name else 'entity'
            base = base if base.endswith('_') else base + '_'
            k = 1
            while f'{base}{k}' in taken:
                k += 1
            name = f'{base}{k}'
        return name

    def _initial_pose(self, request) -> tuple:
        """Return the request's initial pose ``(position, quat)``, or None: the resource's."""
        node = self.node
        pose = request.initial_pose
        position, quat = conv.pose_arrays(pose.pose)
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quat))) or \
                not 1e-6 < float(np.linalg.norm(quat)):
            raise EntityError('INVALID_POSE', 'initial_pose: not finite, or not a rotation')
        if pose.header.frame_id not in ('', node.settings.world_frame):
            # In another frame (an entity's, a body's, a robot link's) where it is now.
            try:
                p_f, R_f, _, _ = self.entities.reference(pose.header.frame_id)
            except EntityError as exc:
                raise EntityError('INVALID_POSE', f'initial_pose.header.frame_id: '
                                                  f'{exc}') from None
            quat = so3.matrix_to_quat(R_f @ so3.quat_to_matrix(quat / np.linalg.norm(quat)))
            position = p_f + R_f @ position
        if np.any(position) or not np.array_equal(quat, [0.0, 0.0, 0.0, 1.0]) \
                or pose.header.frame_id:
            # (the message's default, the identity at the origin, leaves the resource's)
            return position, quat / np.linalg.norm(quat)
        return None

    def _spawned_body(self, request, data: dict, folder: Path) -> tuple:
        """Return ``(RigidBody, shapes, marker)`` of a body spawn, or EntityError (a code)."""
        node = self.node
        taken = set(self.entities.names()) | set(node.sim.bodies.names)
        name = self._free_name(request, request.name or data.get('name') or '', taken)
        try:   # (the name, renamed or not, must make valid topics)
            check_name_token(name, 'name', node.session.full_topic(body_topic(name, 'wrench')))
        except SpecError as exc:
            raise EntityError('NAME_INVALID', str(exc)) from None
        data['name'] = name
        pose = self._initial_pose(request)
        if pose is not None:
            data['position_world'] = pose[0].tolist()
            data['orientation_xyzw'] = pose[1].tolist()
            data.pop('orientation_rpy', None)
        try:
            return body_from_dict(data, folder, 'resource')
        except SpecError as exc:
            missing = 'mesh' in exc.field and ('No such file' in exc.problem
                                               or 'not found' in exc.problem)
            raise EntityError('MISSING_ASSETS' if missing else 'RESOURCE_PARSE_ERROR',
                              str(exc)) from None

    def _spawned_robot(self, request, entry: dict, folder: Path, xml) -> tuple:
        """
        Return ``(RobotSpec, ParsedUrdf, groups)`` of a robot spawn, or EntityError (a code).

        Its links, joints and groups keep their names if they are free; else, with
        allow_renaming, they take the prefix ``<name>_`` (unless the entry gives one).
        Its command groups name its joints as its URDF does (without the prefix).
        """
        node = self.node
        try:
            spec, parsed, groups = robot_from_dict(entry, folder, 'resource', xml)
        except SpecError as exc:
            raise EntityError('RESOURCE_PARSE_ERROR', str(exc)) from None
        missing = [x for x in parsed.ignored if 'file not found' in x]
        if missing and entry.get('collisions'):
            raise EntityError('MISSING_ASSETS', f'resource: {"; ".join(missing)}')
        sim = node.sim
        taken = set(self.entities.names()) | {m.spec.name for m in sim.robots}
        name = self._free_name(request, request.name or spec.name, taken)
        # Its name and pose first: the spec checked below is the one added (converted
        # once, Simulation.robot_model; twice when renamed). An invalid pose is answered
        # after the names, as before.
        spec = replace(spec, name=name)
        try:
            pose, bad_pose = self._initial_pose(request), None
        except EntityError as exc:
            pose, bad_pose = None, exc
        if pose is not None:
            spec = replace(spec, base_xyz=pose[0], base_quat_xyzw=pose[1])

        def clashes(spec, groups) -> list:
            """Return its link, joint, row and group names that are taken."""
            try:
                model = sim.robot_model(spec)
            except SpecError as exc:
                raise EntityError('RESOURCE_PARSE_ERROR', str(exc)) from None
            return sorted((({b.name for b in model.bodies} & set(sim.bodies.names))
                           | ({j.name for j in model.joints} & set(sim.joints.names))
                           | (sim.row_names(model) & sim.taken_names())
                           | ({g.name for g in groups} & set(sim.command_groups()))))
        clash = clashes(spec, groups)
        if clash and 'prefix' not in entry and request.allow_renaming:
            # Its links, joints and groups take the prefix <name>_ (a free entity name).
            spec = replace(spec, prefix=f'{name}_')
            groups = [replace(g, name=f'{name}_{g.name}') for g in groups]
            clash = clashes(spec, groups)
        if clash:
            hint = '' if request.allow_renaming else f' or allow_renaming (prefix {name}_)'
            raise EntityError('NAME_NOT_UNIQUE', f'links, joints or groups {clash[:5]} are '
                                                 f'taken: give the robot a prefix (a YAML robot '
                                                 f'entry){hint}')
        # (its groups name its URDF joints: the prefix, given or not, is prepended)
        groups = [replace(g, joints=[spec.prefix + j for j in g.joints]) for g in groups]
        model = sim.robot_model(spec)
        for field, names, topic in (
                ('link name', [b.name for b in model.bodies], lambda n: body_topic(n, 'wrench')),
                ('joint name', sorted(sim.row_names(model)), constraint_topic)):
            for n in names:
                try:
                    check_name_token(n, field, node.session.full_topic(topic(n)))
                except SpecError as exc:
                    raise EntityError('NAME_INVALID', str(exc)) from None
        for group in groups:
            try:
                check_name_token(group.name, 'command group name',
                                 node.session.full_relative_topic(group_topic(group.name)))
            except SpecError as exc:
                raise EntityError('NAME_INVALID', str(exc)) from None
        if bad_pose is not None:
            raise bad_pose
        return spec, parsed, groups

    def _delete(self, request, response):
        """Remove an entity: a body with its shapes and the constraints that hold it."""
        _, response.result = self._entity_call(lambda: self.entities.get(request.entity))
        if response.result.result != Result.RESULT_OK:
            return response
        entity = self.entities.get(request.entity)
        node = self.node
        before = list(node.sim.bodies.names)
        try:
            gone = node.sim.remove_robot(entity.robot) if entity.category == ROBOT \
                else node.sim.remove_body(entity.body)
        except SpecError as exc:
            response.result = result(Result.RESULT_OPERATION_FAILED, str(exc))
            return response
        node.bodies_changed(before)
        node.publish_now()
        response.result = result(message=f'deleted {request.entity!r} and its constraints '
                                         f'{gone} at t = {node.session.seconds():.9g} s')
        return response

    # -- entities -------------------------------------------------------------------------

    def _selected(self, filters) -> list:
        if filters.tags.tags:
            raise EntityError('FEATURE_UNSUPPORTED', 'filters.tags: entities have no tags here')
        names = self.entities.select(filters.filter, [c.category for c in filters.categories])
        b = filters.bounds
        if b.type == Bounds.TYPE_EMPTY:
            if b.points:
                raise EntityError('OPERATION_FAILED', 'filters.bounds: TYPE_EMPTY with points')
            return names
        kind = {Bounds.TYPE_SPHERE: 'sphere', Bounds.TYPE_BOX: 'box',
                Bounds.TYPE_CONVEX_HULL: 'hull'}.get(b.type)
        if kind is None:
            raise EntityError('OPERATION_FAILED', f'filters.bounds.type: {b.type} is not a '
                                                  f'type of Bounds')
        return self.entities.overlapping(names, kind, [(p.x, p.y, p.z) for p in b.points])

    def _entity_call(self, handler):
        """Run ``handler()``; an EntityError becomes the reply's result (nothing changed)."""
        try:
            return handler(), result()
        except EntityError as exc:
            return None, result(CODES[exc.code], str(exc))

    def _get_entities(self, request, response):
        names, response.result = self._entity_call(lambda: self._selected(request.filters))
        response.entities = names or []
        return response

    def _get_entities_states(self, request, response):
        names, response.result = self._entity_call(lambda: self._selected(request.filters))
        response.entities = names or []
        header = self.header()
        response.states = [conv.entity_state(header, *state)
                           for state in self.entities.states(response.entities)]
        return response

    def _get_entity_state(self, request, response):
        state, response.result = self._entity_call(lambda: self.entities.state(request.entity))
        if state is not None:
            response.state = conv.entity_state(self.header(), *state)
        return response

    def _set_entity_state(self, request, response):
        _, response.result = self._entity_call(lambda: self.entities.get(request.entity))
        if response.result.result != Result.RESULT_OK:
            return response
        frame = request.state.header.frame_id
        frame = '' if frame == self.node.settings.world_frame else frame
        position, quat = conv.pose_arrays(request.state.pose)
        velocity, omega = conv.twist_arrays(request.state.twist)
        values = np.concatenate([position, quat, velocity, omega])
        if not np.all(np.isfinite(values)):
            response.result = result(Result.RESULT_OPERATION_FAILED,
                                     'state: pose and twist must be finite')
            return response
        _, response.result = self._entity_call(lambda: self.entities.set_state(
            request.entity, position, quat, velocity, omega, frame))
        if response.result.result == Result.RESULT_OK:
            self.stopped = False
            self.node.publish_now()
            acc = request.state.acceleration
            if any(not math.isclose(getattr(v, a), 0.0) for v in (acc.linear, acc.angular)
                   for a in 'xyz'):
                response.result.error_message = ('acceleration ignored: it follows from the '
                                                 'forces')
        return response

    def _get_entity_info(self, request, response):
        entity, response.result = self._entity_call(lambda: self.entities.get(request.entity))
        if entity is not None:
            response.info = EntityInfo(description=entity.description, tags=[])
            response.info.category.category = entity.category
        return response

    def _get_entity_bounds(self, request, response):
        box, response.result = self._entity_call(lambda: self.entities.bounds(request.entity))
        if response.result.result == Result.RESULT_OK:
            if box is None:
                response.bounds = Bounds(type=Bounds.TYPE_EMPTY, points=[])
            else:   # (the standard's order: the upper corner, then the lower)
                lower, upper = box
                response.bounds = Bounds(type=Bounds.TYPE_BOX,
                                         points=[conv.vector3(upper), conv.vector3(lower)])
        return response
