"""
The ROS simulator interface (``simulation_interfaces`` 1.0.0) on the node, through DDS.

The node runs in its own process on the test's domain; this process calls its services
and its action. References: the features advertised are exactly those served; the state
machine's transitions and its error codes; steps counted on the published clock (one
``dt`` each); entity states against the closed form of free flight; a state set read
back to rounding and flown from; bounds from the shapes' sizes; every refusal answered
with the standard's code and nothing changed (the state read again is bit for bit the
same).
"""

import math
from pathlib import Path

from action_msgs.msg import GoalStatus
from geometry_msgs.msg import Vector3
import numpy as np
import pytest
from rclpy.action import ActionClient
from rigid_body_sim.ros.conversions import pose_arrays, time_seconds, twist_arrays
from rigid_body_sim.ros.inputs import MAX_TOPIC_LENGTH
from sensor_msgs.msg import JointState
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Bounds, EntityCategory, EntityFilters, EntityState, \
    Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import DeleteEntity, GetEntities, GetEntitiesStates, \
    GetEntityBounds, GetEntityInfo, GetEntityState, GetNamedPoses, GetSimulationState, \
    GetSimulatorFeatures, ResetSimulation, SetEntityState, SetSimulationState, SpawnEntity, \
    StepSimulation
from std_msgs.msg import Float64MultiArray
import yaml

G, DT = 9.81, 1e-3
URDF = Path(__file__).parent / 'urdf' / 'quadruped.urdf'
OK, NOT_FOUND, INCORRECT_STATE, FAILED, UNSUPPORTED = (
    Result.RESULT_OK, Result.RESULT_NOT_FOUND, Result.RESULT_INCORRECT_STATE,
    Result.RESULT_OPERATION_FAILED, Result.RESULT_FEATURE_UNSUPPORTED)
STOPPED, PLAYING, PAUSED, QUITTING = (S := SimulationState).STATE_STOPPED, S.STATE_PLAYING, \
    S.STATE_PAUSED, S.STATE_QUITTING

SCENE = f"""
name: standard
integrator: lie_poisson2
dt: {DT}
effects:
  gravity: {{g_world: [0.0, 0.0, -{G}]}}
bodies:
  - name: ball
    mass: 0.5
    inertia: {{sphere: 0.1}}
    position_world: [0.0, 0.0, 50.0]
    linear_velocity_world: [1.0, 0.0, 2.0]
    shapes: [{{kind: sphere, radius: 0.1}}]
  - name: brick
    mass: 1.0
    inertia: [0.1, 0.2, 0.3]
    position_world: [5.0, 0.0, 50.0]
    shapes: [{{kind: box, size: [0.2, 0.4, 0.6]}}]
  - {{name: bob, mass: 1.0, inertia: [0.01, 0.01, 0.01], position_world: [-5.0, 0.0, 50.0]}}
constraints:
  - {{name: pin, type: ball, body_a: bob, anchor_world: [-5.0, 0.0, 51.0]}}
robots:
  - {{urdf: {URDF}, name: dog, base_pose: {{xyz: [10.0, 0.0, 50.0]}}}}
"""


def _start(ros, tmp_path, paused=True):
    path = tmp_path / 'scene.yaml'
    path.write_text(SCENE)
    return ros.start({'scene': str(path), 'start_paused': paused})


def _call(ros, node, srv_type, name, **fields):
    return ros.client.call(srv_type, name, srv_type.Request(**fields), node=node)


def _state(ros, node, entity):
    reply = _call(ros, node, GetEntityState, 'get_entity_state', entity=entity)
    assert reply.result.result == OK, reply.result.error_message
    s = reply.state
    return (time_seconds(s.header.stamp), *pose_arrays(s.pose), *twist_arrays(s.twist),
            *twist_arrays(s.acceleration))


def _set_state(ros, node, value):
    return _call(ros, node, SetSimulationState, 'set_simulation_state',
                 state=SimulationState(state=value)).result


def _sim_state(ros, node):
    return _call(ros, node, GetSimulationState, 'get_simulation_state').state.state


def _goal(ros, node, steps):
    """Send a goal; return (handle, feedback list) once accepted or rejected."""
    client = ros.client
    action = getattr(client, '_simulate', None) or ActionClient(client.node, SimulateSteps,
                                                                'simulate_steps')
    client._simulate = action
    client.wait_for(action.server_is_ready, 'the simulate_steps action', node=node)
    feedback = []
    sent = action.send_goal_async(SimulateSteps.Goal(steps=steps),
                                  feedback_callback=lambda m: feedback.append(m.feedback))
    client.wait_for(sent.done, 'the goal answered', node=node)
    return sent.result(), feedback


def _outcome(ros, node, handle):
    done = handle.get_result_async()
    ros.client.wait_for(done.done, 'the action result', node=node)
    return done.result().status, done.result().result.result.result


def _simulate(ros, node, steps, cancel_after=None):
    """Run the action; return (status, result, completed feedback, remaining feedback)."""
    handle, feedback = _goal(ros, node, steps)
    if cancel_after is not None:
        ros.client.wait_for(lambda: len(feedback) >= cancel_after, 'feedback', node=node)
        cancel = handle.cancel_goal_async()
        ros.client.wait_for(cancel.done, 'the cancel answered', node=node)
    else:
        # One feedback a step, published before the goal succeeds; but feedback is a topic,
        # apart from the result's service, and rclpy forgets a goal's feedback callback once
        # its result is in: feedback still on its way then is dropped (a fresh-clone CI
        # waited 30 s for it). So every step's feedback is awaited before the result is
        # asked for, unless the goal was refused or ended otherwise (its status: aborted).
        ended = (GoalStatus.STATUS_ABORTED, GoalStatus.STATUS_CANCELED)
        ros.client.wait_for(lambda: len(feedback) >= steps or not handle.accepted
                            or handle.status in ended,
                            "every step's feedback, or the goal's end", node=node)
    status, code = _outcome(ros, node, handle)
    return (status, code, [f.completed_steps for f in feedback],
            [f.remaining_steps for f in feedback])


def _same(a, b):
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b))


def test_features_states_resets_and_steps_answer_as_the_standard_says(ros, tmp_path):
    node = _start(ros, tmp_path, paused=False)
    features = _call(ros, node, GetSimulatorFeatures, 'get_simulator_features').features
    F = SimulatorFeatures
    assert sorted(features.features) == sorted([
        F.SPAWNING, F.DELETING, F.SPAWNING_RESOURCE_STRING,
        F.ENTITY_BOUNDS, F.ENTITY_BOUNDS_BOX, F.ENTITY_BOUNDS_CONVEX, F.ENTITY_CATEGORIES,
        F.ENTITY_STATE_GETTING, F.ENTITY_STATE_SETTING,
        F.ENTITY_INFO_GETTING, F.SIMULATION_RESET, F.SIMULATION_RESET_TIME,
        F.SIMULATION_RESET_STATE, F.SIMULATION_RESET_SPAWNED, F.SIMULATION_STATE_GETTING,
        F.SIMULATION_STATE_SETTING, F.SIMULATION_STATE_PAUSE, F.STEP_SIMULATION_SINGLE,
        F.STEP_SIMULATION_MULTIPLE, F.STEP_SIMULATION_ACTION])
    assert list(features.spawn_formats) == ['urdf', 'xacro', 'yaml']
    # Playing: stepping is refused (INCORRECT_STATE), by the service and the action.
    assert _sim_state(ros, node) == PLAYING
    assert _call(ros, node, StepSimulation, 'step_simulation').result.result == INCORRECT_STATE
    status, code, fb, _ = _simulate(ros, node, 3)
    assert (status, code, fb) == (6, INCORRECT_STATE, [])   # ABORTED
    # Pause; pausing again answers ALREADY_IN_TARGET_STATE.
    assert _set_state(ros, node, PAUSED).result == OK
    codes = SetSimulationState.Response
    assert _set_state(ros, node, PAUSED).result == codes.ALREADY_IN_TARGET_STATE
    assert _set_state(ros, node, 7).result == codes.INCORRECT_TRANSITION
    t0 = _state(ros, node, 'ball')[0]
    # Each step is one dt on the published clock: the service (default one step, then 3) ...
    assert _call(ros, node, StepSimulation, 'step_simulation').result.result == OK
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=3).result.result == OK
    assert _state(ros, node, 'ball')[0] == pytest.approx(t0 + 4 * DT, abs=1e-9)
    # ... and the action, with feedback after every step.
    status, code, completed, remaining = _simulate(ros, node, 5)
    assert (status, code, completed, remaining) == (4, OK, [1, 2, 3, 4, 5], [4, 3, 2, 1, 0])
    assert _state(ros, node, 'ball')[0] == pytest.approx(t0 + 9 * DT, abs=1e-9)
    # Cancelled between steps: it stops there, the clock shows the steps it took.
    status, code, completed, _ = _simulate(ros, node, 1_000_000, cancel_after=2)
    assert status == 5 and code == OK   # CANCELED
    t1 = _state(ros, node, 'ball')[0]
    assert 2 <= round((t1 - t0) / DT) - 9 == completed[-1] < 1_000_000
    # Reset scopes. TIME: the clock to 0, the bodies where they are.
    before = _state(ros, node, 'ball')
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_TIME).result.result == OK
    after = _state(ros, node, 'ball')
    assert after[0] == 0.0 and _same(after[1:5], before[1:5])
    # STATE: the scene's start, the clock running on (one step after the last state).
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=10).result.result == OK
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_STATE).result.result == OK
    start = _state(ros, node, 'ball')
    assert start[0] == pytest.approx(11 * DT, abs=1e-9)
    np.testing.assert_array_equal(start[1], [0.0, 0.0, 50.0])
    np.testing.assert_array_equal(start[3], [1.0, 0.0, 2.0])
    # Bits the standard does not define: refused, nothing changed; SPAWNED: nothing spawned.
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=8).result.result == FAILED
    assert _same(_state(ros, node, 'ball'), start)
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_SPAWNED).result.result == OK
    # ALL: both; the play state is kept (paused).
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=5).result.result == OK
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_ALL).result.result == OK
    assert _state(ros, node, 'ball')[0] == 0.0 and _sim_state(ros, node) == PAUSED
    # STOPPED: paused at the start, t = 0; a step leaves it (PAUSED); it may be paused.
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=5).result.result == OK
    assert _set_state(ros, node, STOPPED).result == OK
    assert _sim_state(ros, node) == STOPPED
    stopped = _state(ros, node, 'ball')
    assert stopped[0] == 0.0 and _same(stopped[1:], _state(ros, node, 'ball')[1:])
    np.testing.assert_array_equal(stopped[1], [0.0, 0.0, 50.0])
    assert _call(ros, node, StepSimulation, 'step_simulation').result.result == OK
    assert _sim_state(ros, node) == PAUSED
    assert _set_state(ros, node, STOPPED).result == OK
    assert _set_state(ros, node, PAUSED).result == OK and _sim_state(ros, node) == PAUSED
    # What is not served answers FEATURE_UNSUPPORTED.
    assert _call(ros, node, GetNamedPoses, 'get_named_poses').result.result == UNSUPPORTED
    # Play, then quit: the node replies and exits cleanly.
    assert _set_state(ros, node, PLAYING).result == OK and _sim_state(ros, node) == PLAYING
    assert _set_state(ros, node, QUITTING).result == OK
    assert node.proc.wait(timeout=30) == 0


def test_entities_states_info_and_bounds_from_the_scene(ros, tmp_path):
    node = _start(ros, tmp_path)
    reply = _call(ros, node, GetEntities, 'get_entities')
    assert reply.result.result == OK and list(reply.entities) == ['ball', 'brick', 'bob', 'dog']
    robots = EntityFilters(categories=[EntityCategory(category=EntityCategory.CATEGORY_ROBOT)])
    assert list(_call(ros, node, GetEntities, 'get_entities', filters=robots).entities) == \
        ['dog']
    assert list(_call(ros, node, GetEntities, 'get_entities',
                      filters=EntityFilters(filter='^b')).entities) == ['ball', 'brick', 'bob']
    bad = _call(ros, node, GetEntities, 'get_entities', filters=EntityFilters(filter='('))
    assert bad.result.result == FAILED and 'regular expression' in bad.result.error_message
    tags = EntityFilters()
    tags.tags.tags = ['red']
    assert _call(ros, node, GetEntities, 'get_entities',
                 filters=tags).result.result == UNSUPPORTED
    # Free flight: p0 + v0 t − g t²/2 (exact in lie_poisson2 to rounding), a = −g.
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=200).result.result == OK
    t, p, q, v, w, a, alpha = _state(ros, node, 'ball')
    assert t == pytest.approx(0.2, abs=1e-9)
    np.testing.assert_allclose(p, [0.2, 0.0, 50.0 + 2.0 * 0.2 - 0.5 * G * 0.04], rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(v, [1.0, 0.0, 2.0 - G * 0.2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a, [0.0, 0.0, -G], rtol=0, atol=1e-12)
    every = _call(ros, node, GetEntitiesStates, 'get_entities_states')
    assert list(every.entities) == ['ball', 'brick', 'bob', 'dog']
    assert pose_arrays(every.states[0].pose)[0].tolist() == p.tolist()
    # A bounds filter: a sphere 0.15 m round a point 0.2 m above the ball (radius 0.1)
    # meets it; 0.05 m round it, not (the entities' own overlap tests: test_entities.py).
    for radius, selected in ((0.15, ['ball']), (0.05, [])):
        near = Bounds(type=Bounds.TYPE_SPHERE, points=[
            Vector3(x=p[0], y=p[1], z=p[2] + 0.2), Vector3(x=radius)])
        reply = _call(ros, node, GetEntities, 'get_entities', filters=EntityFilters(bounds=near))
        assert reply.result.result == OK and list(reply.entities) == selected
    # A state set is read back, and flown from.
    target = EntityState()
    target.pose.position.x, target.pose.position.y, target.pose.position.z = 1.0, 2.0, 30.0
    target.pose.orientation.z, target.pose.orientation.w = math.sin(0.3), math.cos(0.3)
    target.twist.linear.x, target.twist.angular.z = -1.0, 4.0
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='ball',
                 state=target).result.result == OK
    _, p, q, v, w, _, _ = _state(ros, node, 'ball')
    np.testing.assert_allclose(p, [1.0, 2.0, 30.0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(q, [0.0, 0.0, math.sin(0.3), math.cos(0.3)], rtol=0, atol=1e-15)
    np.testing.assert_allclose(v, [-1.0, 0.0, 0.0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(w, [0.0, 0.0, 4.0], rtol=0, atol=1e-14)
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=100).result.result == OK
    np.testing.assert_allclose(_state(ros, node, 'ball')[1],
                               [0.9, 2.0, 30.0 - 0.5 * G * 0.01], rtol=0, atol=1e-12)
    # The robot's state is its base link's; set, it moves as a whole.
    target.twist.angular.z = 0.0
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='dog',
                 state=target).result.result == OK
    _, p, q, v, _, _, _ = _state(ros, node, 'dog')
    np.testing.assert_allclose(p, [1.0, 2.0, 30.0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(v, [-1.0, 0.0, 0.0], rtol=0, atol=1e-13)
    # In another entity's frame: 2 m above the brick (unturned), at rest relative to it.
    relative = EntityState()
    relative.header.frame_id = 'brick'
    relative.pose.position.z = 2.0
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='ball',
                 state=relative).result.result == OK
    _, p_brick, _, v_brick, _, _, _ = _state(ros, node, 'brick')
    _, p, _, v, _, _, _ = _state(ros, node, 'ball')
    np.testing.assert_allclose(p, p_brick + [0.0, 0.0, 2.0], rtol=0, atol=1e-13)
    np.testing.assert_allclose(v, v_brick, rtol=0, atol=1e-13)
    # Refusals, each changing nothing.
    before = [_state(ros, node, e) for e in ('ball', 'bob')]
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='nobody',
                 state=target).result.result == NOT_FOUND
    target.header.frame_id = 'elsewhere'
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='ball',
                 state=target).result.result == FAILED
    target.header.frame_id = ''
    target.pose.position.z = math.nan
    assert _call(ros, node, SetEntityState, 'set_entity_state', entity='ball',
                 state=target).result.result == FAILED
    target.pose.position.z = 30.0
    pinned = _call(ros, node, SetEntityState, 'set_entity_state', entity='bob', state=target)
    assert pinned.result.result == FAILED and "'pin'" in pinned.result.error_message
    after = [_state(ros, node, e) for e in ('ball', 'bob')]
    assert all(_same(a, b) for a, b in zip(before, after))
    assert _call(ros, node, GetEntityState, 'get_entity_state',
                 entity='nobody').result.result == NOT_FOUND
    # Info: categories and descriptions.
    info = _call(ros, node, GetEntityInfo, 'get_entity_info', entity='dog')
    assert info.result.result == OK and info.info.category.category == 1
    assert 'robot' in info.info.description
    assert _call(ros, node, GetEntityInfo, 'get_entity_info',
                 entity='ball').info.category.category == 0
    assert _call(ros, node, GetEntityInfo, 'get_entity_info',
                 entity='x').result.result == NOT_FOUND
    # Bounds about the entity's frame: the box's half sizes, the sphere's radius; none for
    # a body without shapes. (The standard's order: the upper corner first.)
    bounds = _call(ros, node, GetEntityBounds, 'get_entity_bounds', entity='brick').bounds
    assert bounds.type == Bounds.TYPE_BOX
    np.testing.assert_allclose([[c.x, c.y, c.z] for c in bounds.points],
                               [[0.1, 0.2, 0.3], [-0.1, -0.2, -0.3]], rtol=0, atol=1e-15)
    bounds = _call(ros, node, GetEntityBounds, 'get_entity_bounds', entity='ball').bounds
    np.testing.assert_allclose([[c.x, c.y, c.z] for c in bounds.points],
                               [[0.1] * 3, [-0.1] * 3], rtol=0, atol=1e-15)
    assert _call(ros, node, GetEntityBounds, 'get_entity_bounds',
                 entity='bob').bounds.type == Bounds.TYPE_EMPTY


def test_a_running_action_is_alone_and_ends_on_a_reset_and_on_quitting(ros, tmp_path):
    node = _start(ros, tmp_path)
    first, feedback = _goal(ros, node, 1_000_000)
    assert first.accepted
    ros.client.wait_for(lambda: len(feedback) >= 1, 'feedback', node=node)
    second, _ = _goal(ros, node, 5)
    assert not second.accepted   # (one goal at a time)
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_ALL).result.result == OK
    assert _outcome(ros, node, first) == (6, FAILED)   # ABORTED: the simulation was reset
    assert _sim_state(ros, node) == PAUSED and _state(ros, node, 'ball')[0] == 0.0
    # STOPPED stays STOPPED through a reset of everything (paused at the start, t = 0).
    assert _set_state(ros, node, STOPPED).result == OK
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_ALL).result.result == OK
    assert _sim_state(ros, node) == STOPPED
    # Quitting while a goal runs: the goal is answered, then the node exits cleanly.
    running, feedback = _goal(ros, node, 1_000_000)
    result = running.get_result_async()   # (asked for at once, as clients do)
    ros.client.wait_for(lambda: len(feedback) >= 1, 'feedback', node=node)
    assert _set_state(ros, node, QUITTING).result == OK
    ros.client.wait_for(result.done, 'the action result', node=node)
    assert (result.result().status, result.result().result.result.result) == (6, FAILED)
    assert node.proc.wait(timeout=30) == 0


#: The scene above without its robot and without the ball.
SPAWN_SCENE = yaml.safe_dump({**{k: v for k, v in yaml.safe_load(SCENE).items() if k != 'robots'},
                              'name': 'spawning',
                              'bodies': [b for b in yaml.safe_load(SCENE)['bodies']
                                         if b['name'] != 'ball']})
CRATE = ('{name: crate, mass: 2.0, inertia: {box: [0.2, 0.2, 0.2]}, '
         'shapes: [{kind: box, size: [0.2, 0.2, 0.2]}]}')


def _spawn(ros, node, resource=CRATE, name='', x=0.0, y=3.0, z=20.0, **fields):
    request = SpawnEntity.Request(name=name, resource_string=resource, **fields)
    request.initial_pose.pose.position.x = x
    request.initial_pose.pose.position.y = y
    request.initial_pose.pose.position.z = z
    return ros.client.call(SpawnEntity, 'spawn_entity', request, node=node)


def _entities(ros, node):
    return list(_call(ros, node, GetEntities, 'get_entities').entities)


def _topics(ros):
    return {n for n, _ in ros.client.node.get_topic_names_and_types()}


def test_bodies_spawned_and_deleted_at_run_time(ros, tmp_path):
    path = tmp_path / 'scene.yaml'
    path.write_text(SPAWN_SCENE)
    node = ros.start({'scene': str(path), 'start_paused': True})
    codes = SpawnEntity.Response
    assert _entities(ros, node) == ['brick', 'bob']
    reply = _spawn(ros, node)
    assert reply.result.result == OK and reply.entity_name == 'crate'
    assert _entities(ros, node) == ['brick', 'bob', 'crate']
    pose_topic = '/rigid_body_sim/bodies/crate/pose'
    ros.client.wait_for(lambda: pose_topic in _topics(ros), pose_topic, node=node)
    # It falls from its initial pose: z0 − g t²/2 (lie_poisson2: exact to rounding).
    t0 = _state(ros, node, 'crate')[0]
    assert _call(ros, node, StepSimulation, 'step_simulation', steps=100).result.result == OK
    t, p = _state(ros, node, 'crate')[:2]
    assert t == pytest.approx(t0 + 0.1, abs=1e-9)
    np.testing.assert_allclose(p, [0.0, 3.0, 20.0 - 0.5 * G * 0.01], rtol=0, atol=1e-12)
    # Names: taken (refused, or renamed when allowed).
    assert _spawn(ros, node, x=9.0).result.result == codes.NAME_NOT_UNIQUE
    renamed = _spawn(ros, node, x=9.0, allow_renaming=True)
    assert renamed.result.result == OK and renamed.entity_name == 'crate_1'
    # Renaming keeps names tokens (no '__'); an empty name is generated; too long a name
    # (once numbered) is refused; a uri, when given, wins over resource_string.
    under = _spawn(ros, node, resource=CRATE.replace('crate', 'box_'), x=12.0)
    assert under.entity_name == 'box_'
    again = _spawn(ros, node, resource=CRATE.replace('crate', 'box_'), x=14.0,
                   allow_renaming=True)
    assert again.result.result == OK and again.entity_name == 'box_1'
    nameless = _spawn(ros, node, resource=CRATE.replace('name: crate, ', ''), x=16.0,
                      allow_renaming=True)
    assert nameless.result.result == OK and nameless.entity_name == 'entity_1'
    # (the longest a name may be: its wrench topic at ROS's length limit)
    long = 'x' * (MAX_TOPIC_LENGTH - len('/rigid_body_sim/bodies//wrench'))
    assert _spawn(ros, node, name=long, x=18.0).result.result == OK
    assert _spawn(ros, node, name=long, x=20.0,
                  allow_renaming=True).result.result == codes.NAME_INVALID
    (tmp_path / 'other.yaml').write_text(CRATE.replace('crate', 'from_uri'))
    both = _spawn(ros, node, uri=str(tmp_path / 'other.yaml'), x=22.0)
    assert both.result.result == OK and both.entity_name == 'from_uri'
    # Refusals, each with the standard's code, changing nothing.
    before = (_entities(ros, node), _state(ros, node, 'crate'), _state(ros, node, 'brick'))
    missing_mesh = ('{name: m, mass: 1.0, inertia: [0.1, 0.1, 0.1], shapes: [{kind: mesh, '
                    f'mesh: {tmp_path / "absent.stl"}}}]}}')
    for fields, code in (
            ({'name': 'a b'}, codes.NAME_INVALID),
            ({'resource': ''}, codes.NO_RESOURCE),
            ({'resource': '<sdf version="1.9"/>'}, codes.UNSUPPORTED_FORMAT),
            ({'resource': '', 'uri': str(tmp_path / 'r.sdf')}, codes.UNSUPPORTED_FORMAT),
            ({'resource': '<robot name="r"/>'}, codes.RESOURCE_PARSE_ERROR),
            ({'resource': 'name: [unclosed'}, codes.RESOURCE_PARSE_ERROR),
            ({'resource': '{name: n, inertia: [1, 1, 1]}'}, codes.RESOURCE_PARSE_ERROR),
            ({'resource': missing_mesh}, codes.MISSING_ASSETS),
            ({'name': 'c2', 'x': 5.0, 'y': 0.0, 'z': 50.2}, codes.INVALID_POSE),   # in brick
            ({'name': 'c3', 'z': math.nan}, codes.INVALID_POSE)):
        reply = _spawn(ros, node, **fields)
        assert reply.result.result == code, (fields, reply.result.error_message)
    assert before[0] == _entities(ros, node)
    assert _same(before[1], _state(ros, node, 'crate'))
    assert _same(before[2], _state(ros, node, 'brick'))
    # A spawn from a file (its format by its suffix).
    (tmp_path / 'crate.yaml').write_text(CRATE)
    from_file = _spawn(ros, node, resource='', uri=f'file://{tmp_path / "crate.yaml"}',
                       name='filed', x=-9.0)
    assert from_file.result.result == OK and from_file.entity_name == 'filed'
    # Deleting: its constraints named, its topics gone; an unknown one NOT_FOUND.
    deleted = _call(ros, node, DeleteEntity, 'delete_entity', entity='bob')
    assert deleted.result.result == OK and "['pin']" in deleted.result.error_message
    assert 'bob' not in _entities(ros, node)
    ros.client.wait_for(lambda: '/rigid_body_sim/bodies/bob/pose' not in _topics(ros),
                        "bob's topics gone", node=node)
    assert _call(ros, node, DeleteEntity, 'delete_entity',
                 entity='bob').result.result == NOT_FOUND
    # Resets: SPAWNED removes what was spawned; ALL brings the scene back as loaded.
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_SPAWNED).result.result == OK
    assert _entities(ros, node) == ['brick']   # (spawned ones gone, bob still deleted)
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_ALL).result.result == OK
    assert _entities(ros, node) == ['brick', 'bob']
    np.testing.assert_array_equal(_state(ros, node, 'bob')[1], [-5.0, 0.0, 50.0])


ARM = Path(__file__).resolve().parent.parent / 'config' / 'servo_arm.urdf'


def test_robots_spawned_into_a_running_node_take_joint_commands_and_are_deleted(
        ros, tmp_path):
    # The node plays; two arms are spawned, one from a URDF file (its joints take
    # efforts), one from our YAML robot entry with an exact position drive group; the
    # group's commands on <group>/commands bring its joints to their targets (the
    # drive's row: the error decays as exp(-t / 0.05 s), within 1e-3 rad after 0.35 s).
    path = tmp_path / 'scene.yaml'
    path.write_text(SPAWN_SCENE)
    node = ros.start({'scene': str(path), 'start_paused': False})
    codes = SpawnEntity.Response
    states = ros.client.subscribe(JointState, '/joint_states')
    plain = _spawn(ros, node, resource='', uri=str(ARM), x=0.0, y=-5.0, z=0.0)
    assert plain.result.result == OK, plain.result.error_message
    assert plain.entity_name == 'servo_arm'
    # The same URDF again: its links are taken; renamed, it takes the prefix <name>_.
    text = ARM.read_text()
    assert _spawn(ros, node, resource=text, name='arm2', y=5.0,
                  z=0.0).result.result == codes.NAME_NOT_UNIQUE
    entry = yaml.safe_dump({'urdf': str(ARM), 'name': 'arm2', 'command_groups': [
        {'name': 'reach', 'joints': ['shoulder', 'elbow'], 'interface': 'position',
         'mode': 'exact'}]})
    second = _spawn(ros, node, resource=entry, allow_renaming=True, x=0.0, y=5.0, z=0.0)
    assert second.result.result == OK, second.result.error_message
    assert second.entity_name == 'arm2'   # (its links, joints and group: prefix arm2_)
    # The same entry again: taken, then renamed whole (entity, links, joints, group).
    assert _spawn(ros, node, resource=entry, x=0.0, y=9.0,
                  z=0.0).result.result == codes.NAME_NOT_UNIQUE
    third = _spawn(ros, node, resource=entry, allow_renaming=True, x=0.0, y=9.0, z=0.0)
    assert third.result.result == OK and third.entity_name == 'arm2_1'
    # A joint whose name makes no topic (its reaction's): refused, nothing spawned.
    bad = text.replace('<joint name="elbow"', '<joint name="elbow-joint"')
    assert _spawn(ros, node, resource=bad, name='bad', allow_renaming=True, y=12.0,
                  z=0.0).result.result == codes.NAME_INVALID
    assert _entities(ros, node) == ['brick', 'bob', 'servo_arm', 'arm2', 'arm2_1']
    assert _call(ros, node, DeleteEntity, 'delete_entity',
                 entity='arm2_1').result.result == OK
    names = ['shoulder', 'elbow', 'wrist', 'arm2_shoulder', 'arm2_elbow', 'arm2_wrist']
    ros.client.wait_for(lambda: states and list(states[-1].name) == names,
                        'joint_states of both arms', node=node)
    group = ros.client.node.create_publisher(Float64MultiArray,
                                             '/arm2_reach/commands', 10)
    ros.client.wait_for(lambda: group.get_subscription_count() > 0, 'the group subscribed',
                        node=node)

    def reached():
        if not states:
            return False
        q = dict(zip(states[-1].name, states[-1].position))
        return abs(q['arm2_shoulder'] - 0.5) < 1e-3 and abs(q['arm2_elbow'] + 0.3) < 1e-3
    group.publish(Float64MultiArray(data=[0.5, -0.3]))
    ros.client.wait_for(reached, 'arm2 at its targets', node=node)
    # Its state: its root link's (its URDF's 'world' link: where it was spawned, at rest).
    state = _state(ros, node, 'arm2')
    np.testing.assert_array_equal(state[1], [0.0, 5.0, 0.0])
    np.testing.assert_array_equal(state[3], [0.0, 0.0, 0.0])
    # Deleting a robot: its joints leave joint_states, its group's topic goes.
    deleted = _call(ros, node, DeleteEntity, 'delete_entity', entity='servo_arm')
    assert deleted.result.result == OK, deleted.result.error_message
    ros.client.wait_for(lambda: list(states[-1].name) == names[3:],
                        'joint_states without servo_arm', node=node)
    assert _call(ros, node, ResetSimulation, 'reset_simulation',
                 scope=ResetSimulation.Request.SCOPE_SPAWNED).result.result == OK
    assert _entities(ros, node) == ['brick', 'bob']
    ros.client.wait_for(
        lambda: group.get_subscription_count() == 0
        and '/rigid_body_sim/bodies/arm2_hand/pose' not in _topics(ros),
        "arm2's topics gone", node=node)


def test_a_hundred_bodies_spawned_one_after_another_into_a_node_at_1_khz(ros, tmp_path):
    # The node plays at 1 kHz while 100 crates are spawned back to back (each call waits
    # for its reply). Each spawn rebuilds the simulation between two steps; no step may be
    # lost or doubled and no state perturbed: after a pause, every crate has fallen freely
    # from rest where it was spawned (lie_poisson2 is exact for uniform gravity: the drop
    # is v²/2g to rounding, its x and y as spawned), the earlier ones faster; the brick,
    # falling since t = 0 through all 100 rebuilds, is on its closed form at the stamp's
    # time. (The lag resets the spawns cause are timing, measured in
    # bench/node_spawning.py, not asserted.)
    path = tmp_path / 'scene.yaml'
    path.write_text(SPAWN_SCENE)
    node = ros.start({'scene': str(path), 'start_paused': False, 'physics_rate': 1000.0})
    for k in range(100):
        reply = _spawn(ros, node, name=f'c{k}', x=float(k), y=-3.0, z=100.0)
        assert reply.result.result == OK, reply.result.error_message
    assert _set_state(ros, node, PAUSED).result == OK
    every = _call(ros, node, GetEntitiesStates, 'get_entities_states')
    states = dict(zip(every.entities, every.states))
    stamps = {time_seconds(s.header.stamp) for s in every.states}
    assert len(stamps) == 1
    t = stamps.pop()
    speeds = []
    for k in range(100):
        p = pose_arrays(states[f'c{k}'].pose)[0]
        v = twist_arrays(states[f'c{k}'].twist)[0]
        np.testing.assert_array_equal(p[:2], [float(k), -3.0])
        assert v[2] < 0.0 and v[0] == v[1] == 0.0
        assert 100.0 - p[2] == pytest.approx(v[2] ** 2 / (2 * G), rel=1e-9, abs=1e-12)
        speeds.append(-v[2])
    assert all(a >= b for a, b in zip(speeds, speeds[1:]))
    p = pose_arrays(states['brick'].pose)[0]
    np.testing.assert_allclose(p, [5.0, 0.0, 50.0 - 0.5 * G * t * t], rtol=0, atol=1e-9)
