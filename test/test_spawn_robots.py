"""
Robots added and removed at run time, and bodies spawned into scenes with joints.

``Simulation.add_robot``, ``remove_robot``; ``add_body`` and ``remove_body`` with robots
present. References:

- the same run without the spawn: a robot whose joints are, at the spawn, in every mode
  the events keep (a bound held, a stick, a slip, a drive saturated towards its velocity
  target, a servo, a continuous joint past a turn, held effort commands) goes on as if
  nothing was spawned, to the solvers' tolerances (the rebuild restarts their warm
  starts: the constraint solve stops within 1e-10 of Φ and of its velocity law, so a
  restart moves a coordinate by far less than 1e-9 over 0.5 s; measured 1e-16), with
  its modes, turns and counters;
- a robot spawned at t₀ into a scene moves as the same robot started alone at 0 (its
  equations are autonomous and nothing touches it): the same coordinates after the same
  steps, to the same tolerance;
- the same spawns and removals at the same steps give bit-identical runs;
- a removal takes the robot's links, joints, groups and the constraints that hold its
  links (named); every refusal names its field and changes nothing.
"""

from dataclasses import replace

import numpy as np
import pytest

from rigid_body_sim.core import Constraint, RigidBody, SpecError
from rigid_body_sim.core.robots import CommandGroup
from rigid_body_sim.scene import scene_from_dict
from robot_helpers import inertial, joint, link, robot

G = 9.81
#: rad or m, rad/s or m/s: two runs' joint coordinates and rates after a restart of the
#: solvers' warm starts (module docstring).
TOL_Q, TOL_V = 1e-9, 1e-7


def _modes_urdf():
    """Five joints on a fixed base, one per mode at the spawn (module docstring)."""
    arm = inertial(1.0, xyz=(0.3, 0, 0), ixx=0.01, iyy=0.01, izz=0.01)
    disc = inertial(1.0, xyz=(0.1, 0, 0), ixx=0.01, iyy=0.01, izz=0.01)
    return robot(
        'modes', link('world'),
        *(link(n, arm if n == 'pendulum' else disc)
          for n in ('pendulum', 'stuck', 'spinner', 'wheel', 'servoed')),
        # Falls onto its upper bound (0.5 rad) under gravity and rests there: a bound held.
        joint('limit', 'revolute', 'world', 'pendulum', xyz=(0, 0, 1), axis=(0, 1, 0),
              extra='<limit effort="1e6" velocity="1e6" lower="-0.5" upper="0.5"/>'),
        # A vertical axis, 1 N m commanded against 5 N m of friction: it sticks.
        joint('stick', 'revolute', 'world', 'stuck', xyz=(1, 0, 1), axis=(0, 0, 1),
              extra='<limit effort="1e6" velocity="1e6" lower="-3" upper="3"/>'
                    '<dynamics friction="5.0"/>'),
        # 2 N m against 0.1 N m: it slips and spins up past a turn.
        joint('slip', 'continuous', 'world', 'spinner', xyz=(2, 0, 1), axis=(0, 0, 1),
              extra='<limit effort="1e6" velocity="1e6"/><dynamics friction="0.1"/>'),
        # Asked for 50 rad/s with 0.5 N m at most: saturated for 4 s.
        joint('axle', 'continuous', 'world', 'wheel', xyz=(3, 0, 1), axis=(0, 0, 1),
              extra='<limit effort="0.5" velocity="1e6"/>'),
        joint('servo', 'revolute', 'world', 'servoed', xyz=(4, 0, 1), axis=(0, 0, 1)))


def _groups(prefix=''):
    return [CommandGroup(f'{prefix}wheel', [f'{prefix}axle'], 'velocity', 'exact'),
            CommandGroup(f'{prefix}servo', [f'{prefix}servo'], 'position', 'servo',
                         kp=20.0, kd=2.0)]


def _scene(tmp_path, bodies=True, events=True):
    """Return the modes robot, with a pendulum ``bob`` (``bodies``); ``events``: see _robot."""
    path = tmp_path / 'modes.urdf'
    path.write_text(_modes_urdf())
    data = {'dt': 1e-3, 'effects': {'gravity': {'g_world': [0.0, 0.0, -G]}},
            'robots': [{'urdf': str(path), 'limits': events, 'friction': events,
                        'effort_limits': events}],
            'command_groups': [{'name': g.name, 'joints': list(g.joints),
                                'interface': g.interface.value, 'mode': g.mode,
                                'kp': g.kp, 'kd': g.kd} for g in _groups()]}
    if bodies:
        data['bodies'] = [{'name': 'bob', 'mass': 1.0, 'inertia': [0.01, 0.01, 0.01],
                           'position_world': [0.0, 3.0, 1.0]}]
        data['constraints'] = [{'name': 'rope', 'type': 'ball', 'body_a': 'bob',
                                'body_b': 'world', 'anchor_world': [0.0, 3.0, 2.0]}]
    sim = scene_from_dict(data, str(tmp_path / 's.yaml')).simulation
    sim.command_joints({'stick': 1.0, 'slip': 2.0, 'axle': 50.0, 'servo': 1.0})
    return sim


def _robot(tmp_path, prefix, events=True):
    """
    Return the modes robot as a RobotSpec (its links and joints ``prefix``-ed).

    ``events`` False: without limits, friction and effort limits (no events: a located
    event splits every body's step, and so changes the others' truncation error).
    """
    sim = _scene(tmp_path, bodies=False)
    spec = sim.robots[0].spec
    return replace(spec, prefix=prefix, name=prefix + spec.name, base_xyz=(0.0, -3.0, 0.0),
                   enforce_limits=events, enforce_friction=events, enforce_efforts=events)


def _modes(sim, prefix=''):
    """Return what the events keep (names without ``prefix``), and the counters."""
    def strip(d):
        return {k[len(prefix):]: v for k, v in d.items() if k.startswith(prefix)}
    fr, lim, dr = sim.joint_friction(), sim.joint_limits(), sim.drive_saturation()
    return (sorted(n[len(prefix):] for n in fr['sticking'] if n.startswith(prefix)),
            strip(fr['slipping']), strip(lim['active']), strip(dr['saturated']))


def _joints(sim, prefix=''):
    names = [n for n in sim.joint_names() if n.startswith(prefix)]
    js = sim.joint_state(names)
    return np.array(js.positions), np.array(js.velocities)


def _assert_close(a, b):
    np.testing.assert_allclose(a[0], b[0], rtol=0, atol=TOL_Q)
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=TOL_V)


def test_every_joint_mode_goes_on_across_a_spawn_and_a_removal(tmp_path):
    sim, ref = _scene(tmp_path), _scene(tmp_path)
    for s in (sim, ref):
        s.step(700)
        s.apply_wrench('bob', force=(0.5, 0.0, 0.0), key='push')
    modes = _modes(sim)
    assert modes == (['stick'], {'slip': 1}, {'limit': 'upper'}, {'axle': 1})
    assert sim.joint_state(['slip']).positions[0] > 2 * np.pi   # (past a turn)
    sim.add_body(RigidBody('far', 1.0, (0.1,) * 3, position_world=(0.0, 10.0, 5.0)))
    assert _modes(sim) == modes and sim.joint_counters() == ref.joint_counters()
    assert sim.drive_saturation()['counters'] == ref.drive_saturation()['counters']
    sim.step(500)
    ref.step(500)
    _assert_close(_joints(sim), _joints(ref))
    assert _modes(sim) == _modes(ref)
    np.testing.assert_allclose(sim.pose('bob')[0], ref.pose('bob')[0], rtol=0, atol=TOL_Q)
    assert sim.remove_body('far') == []
    sim.step(300)
    ref.step(300)
    _assert_close(_joints(sim), _joints(ref))
    assert _modes(sim) == _modes(ref)
    # A robot with events spawned into it: at the spawn the others' state is the same bits
    # (the new robot's sticks and bounds take nothing from them) and their modes go on.
    before = _modes(sim), [p.copy() for p in sim.state.parts]
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    n = len(before[1][0])
    sticking, slipping, active, saturated = _modes(sim)
    assert (sorted(n for n in sticking if not n.startswith('b_')), slipping, active,
            saturated) == before[0]
    # (the spawned robot at rest: its friction joints stick, nothing else)
    assert _modes(sim, 'b_') == (['slip', 'stick'], {}, {}, {})
    assert all(np.array_equal(p[:n], q) for p, q in zip(sim.state.parts, before[1]))


def test_a_spawned_robot_moves_as_the_same_robot_started_alone(tmp_path):
    # Into a scene without events (a located event splits every body's step, and so
    # changes the others' truncation error): the spawned robot's steps are split where
    # the lone robot's are, and the two see the same steps.
    sim = _scene(tmp_path, events=False)
    sim.step(250)
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    assert sim.spawned_robots == ['b_modes'] and len(sim.joint_names()) == 10
    sim.command_joints({'b_stick': 1.0, 'b_slip': 2.0, 'b_axle': 50.0, 'b_servo': 1.0})
    alone = _scene(tmp_path, bodies=False)
    for n in (300, 400):
        sim.step(n)
        alone.step(n)
        _assert_close(_joints(sim, 'b_'), _joints(alone))
        assert _modes(sim, 'b_') == _modes(alone)
    # The spawned robot's servo and drive answer commands.
    sim.command_joints({'b_servo': -0.5, 'b_axle': 0.0})
    alone.command_joints({'servo': -0.5, 'axle': 0.0})
    sim.step(300)
    alone.step(300)
    _assert_close(_joints(sim, 'b_'), _joints(alone))


def test_removing_a_robot_takes_its_links_joints_groups_and_the_constraints_on_them(tmp_path):
    sim, ref = _scene(tmp_path), _scene(tmp_path)
    sim.step(100)
    ref.step(100)
    sim.add_robot(_robot(tmp_path, 'b_', events=False), _groups('b_'))
    sim.add_constraint(Constraint('leash', 'ball', 'bob', 'b_pendulum',
                                  anchor_world=(0.0, 0.0, 1.0)))
    sim.step(200)
    with pytest.raises(SpecError, match="'b_pendulum' is a link of robot 'b_modes'"):
        sim.remove_body('b_pendulum')
    assert sim.remove_robot('b_modes') == ['leash']
    assert sim.robots[0].spec.name == 'modes' and sorted(sim.command_groups()) == [
        'servo', 'wheel']
    assert 'b_axle' not in sim.joint_names() and 'b_pendulum' not in sim.bodies.index
    assert sim.constraint_names == ref.constraint_names
    with pytest.raises(SpecError, match="no robot 'b_modes'"):
        sim.remove_robot('b_modes')
    # The bob was tied to the removed robot for 0.2 s: the first robot only goes on.
    ref.step(200)
    sim.step(300)
    ref.step(300)
    _assert_close(_joints(sim), _joints(ref))
    assert sim.remove_body('bob') == ['rope']


def test_a_joint_removed_stays_removed_and_a_robot_may_not_take_a_constraints_name(tmp_path):
    sim = _scene(tmp_path)
    sim.step(10)
    sim.remove_constraint('servo')   # (the servoed link's hinge: the link goes free)
    sim.add_body(RigidBody('far', 1.0, (0.1,) * 3, position_world=(0.0, 10.0, 5.0)))
    assert 'servo' not in sim.constraint_names
    sim.add_constraint(Constraint('b_servo', 'ball', 'bob', None, anchor_world=(0, 3, 1)))
    before = sim.state.y.copy()
    with pytest.raises(SpecError, match=r"constraints named \['b_servo'\]") as err:
        sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    assert err.value.field == 'robot' and np.array_equal(sim.state.y, before)
    # Removed with its robot, the name is free again for the next one.
    sim.remove_constraint('b_servo')
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    assert sim.constraint_spec('b_servo').type.value == 'hinge'
    sim.remove_robot('b_modes')
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    assert 'b_servo' in sim.constraint_names


def test_the_same_robot_spawns_and_removals_give_bit_identical_runs(tmp_path):
    runs = []
    for _ in range(2):
        sim = _scene(tmp_path)
        sim.step(150)
        sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
        sim.command_joints({'b_slip': 2.0, 'b_axle': 20.0})
        sim.step(200)
        sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(0, 10, 1)))
        sim.step(100)
        sim.remove_robot('b_modes')
        sim.step(100)
        runs.append((sim.state.y.copy(), _joints(sim)))
    assert np.array_equal(runs[0][0], runs[1][0])
    assert all(np.array_equal(a, b) for a, b in zip(runs[0][1], runs[1][1]))


@pytest.mark.parametrize('change, field, words', [
    (lambda sim, tp: sim.add_robot(_robot(tp, '')), 'robot.name', "'modes' is taken"),
    (lambda sim, tp: sim.add_robot('arm'), 'robot', 'expected a RobotSpec'),
    (lambda sim, tp: sim.add_robot(_robot(tp, 'b_'), _groups('')), 'command_groups[0].name',
     "'wheel' is taken"),
    (lambda sim, tp: sim.add_robot(_robot(tp, 'b_'), [CommandGroup('x', ['axle'])]),
     'command_groups[0].joints[0]', "'axle' is a joint already"),
    (lambda sim, tp: sim.add_robot(_robot(tp, 'b_'), [CommandGroup('x', ['b_servo'], 'position',
                                                                   'servo', kp=1e9)]),
     'command_groups', 'unstable'),
    (lambda sim, tp: sim.remove_body('pendulum'), 'name', 'a link of robot'),
])
def test_a_refused_robot_change_names_its_field_and_changes_nothing(tmp_path, change, field,
                                                                    words):
    sim, ref = _scene(tmp_path), _scene(tmp_path)
    sim.step(50)
    ref.step(50)
    with pytest.raises(SpecError) as err:
        change(sim, tmp_path)
    assert err.value.field.startswith(field) and words in str(err.value)
    sim.step(100)
    ref.step(100)
    assert np.array_equal(sim.state.y, ref.state.y)
    assert sim.joint_names() == ref.joint_names()


def test_reset_scene_and_remove_spawned_take_spawned_robots_away(tmp_path):
    sim = _scene(tmp_path)
    sim.step(10)
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    sim.add_body(RigidBody('c', 1.0, (0.1,) * 3, position_world=(0, 10, 1)))
    assert sim.scene_changed
    assert sim.remove_spawned() == ['c', 'b_modes']
    assert [m.spec.name for m in sim.robots] == ['modes'] and not sim.scene_changed
    assert sorted(sim.command_groups()) == ['servo', 'wheel'] and sim.spawned_robots == []
    sim.add_robot(_robot(tmp_path, 'b_'), _groups('b_'))
    sim.step(5)
    sim.reset_scene()
    assert [m.spec.name for m in sim.robots] == ['modes'] and sim.time == 0.0
    assert not sim.scene_changed and sim.spawned_robots == []
    assert sorted(sim.command_groups()) == ['servo', 'wheel']
    assert np.array_equal(sim.state.y, _scene(tmp_path).state.y)


def test_a_robot_may_not_take_another_robots_possible_rows_and_a_refusal_caches_nothing(
        tmp_path):
    # 'servo_limit' and 'servo_stick' are the rows that would hold the first robot's servo
    # on a bound or by friction (it has neither now): a robot prefixed 'servo_' makes joints
    # of those names ('limit', 'stick'), and is refused by name, before any rebuild.
    sim = _scene(tmp_path)
    with pytest.raises(SpecError, match=r"named \['servo_limit', 'servo_stick'\]") as err:
        sim.add_robot(_robot(tmp_path, 'servo_'))
    assert err.value.field == 'robot'
    # A refused spec leaves no conversion behind: changed in place and added again, it is
    # converted anew (its servo at the new initial position).
    spec = _robot(tmp_path, 'b_')
    sim.add_constraint(Constraint('b_servo', 'ball', 'bob', None, anchor_world=(0, 3, 1)))
    with pytest.raises(SpecError):
        sim.add_robot(spec)
    sim.remove_constraint('b_servo')
    spec.initial_positions['servo'] = 0.7
    sim.add_robot(spec, _groups('b_'))
    assert sim.joint_state(['b_servo']).positions[0] == pytest.approx(0.7, abs=1e-12)
    # So too a spec asked about first (robot_model: converted once for a check and the
    # add), refused on a group name before its conversion is taken.
    spec = _robot(tmp_path, 'c_')
    assert sim.robot_model(spec) is sim.robot_model(spec)
    with pytest.raises(SpecError, match="'wheel' is taken"):
        sim.add_robot(spec, _groups(''))
    spec.initial_positions['servo'] = -0.4
    sim.add_robot(spec, _groups('c_'))
    assert sim.joint_state(['c_servo']).positions[0] == pytest.approx(-0.4, abs=1e-12)


def test_a_spawn_plans_only_the_components_it_changes_and_copies_step_as_plans_do(
        tmp_path, monkeypatch):
    # The compiled steps' components (a connected set of bodies and joints each: here the
    # modes robot's five joints on the world, and bob on its rope) are planned and packed
    # once; a rebuild copies those whose rows and bodies are the same (the solver's plans)
    # and plans only what a spawn or a removal changed. A copy must step exactly as a
    # component planned afresh (the same run with no plan ever copied).
    def run():
        sim = _scene(tmp_path, events=False)
        sim.step(120)
        counts = []
        for change in (lambda: sim.add_body(RigidBody('far', 1.0, (0.1,) * 3,
                                                      position_world=(0.0, 10.0, 5.0))),
                       lambda: sim.add_robot(_robot(tmp_path, 'b_', events=False),
                                             _groups('b_')),
                       lambda: sim.remove_robot('b_modes'),
                       lambda: sim.remove_body('far')):
            change()
            counts.append(dict(sim.dynamics.solver.plan_counts))
            sim.step(80)
        return sim, counts

    sim, counts = run()
    # (no content: every component is planned, as one with Python rows is)
    monkeypatch.setattr('rigid_body_sim.core.solver._content', lambda *args: None)
    fresh, fresh_counts = run()
    assert np.array_equal(sim.state.y, fresh.state.y)
    assert all(np.array_equal(a, b) for a, b in zip(_joints(sim), _joints(fresh)))
    # Planned anew: nothing for a free body spawned or removed; for the robot's spawn its
    # five components, one of them twice (its exact drive's, before and after the reset
    # adds the drive's row); nothing for its removal. Every other component copied.
    assert [c['planned'] for c in counts] == [0, 6, 0, 0]
    assert [c['copied'] > 0 for c in counts] == [True] * 4
    assert all(c['copied'] == 0 for c in fresh_counts)
    assert [c['planned'] for c in fresh_counts][0] >= 6
